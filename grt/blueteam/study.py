"""One blue-team study (paper Table 3): fine-tune a red-team run's policy on its CrashShapes, score it
before and after on the same held-out episodes, and optionally red-team it again.

Writes into its own folder (``outputs/blueteam/<time>``): ``policy.pt`` (the fine-tuned checkpoint,
config inside), ``metrics.csv`` and ``curve.png`` (training), ``validation.json`` / ``validation.jsonl`` /
``validation.png`` (early stopping), ``confirm.json`` (the best validated checkpoints, kept in
``candidates/``, re-scored on fresh episodes; the exported one is chosen on validation and confirmation
pooled), ``scores.json`` (every geometry before and after, per trial), ``table3.json`` / ``table3.md``
(the paper's Table 3 columns plus held-out shapes), ``blueteam.json`` and, with
``blueteam.rered.enabled``, a re-red-team run of the fine-tuned policy under ``rered/`` with the original
run's budget and seed. Started again in the same folder, a killed study continues; a resume
(``resume=DIR``) goes on with the study's own config (:func:`grt.cli.blueteam.resumed_config`).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from grt.agreement import SwapCheckSettings
from grt.blueteam.core import (
    BlueTeamError,
    Geometry,
    check_guard,
    distinct,
    failing_records,
    load_run,
    make_evaluator,
    name_of,
    run_geometry,
    select_crashshapes,
    trainable_checkpoint,
    write_table,
)
from grt.blueteam.finetune import fine_tune
from grt.config import at_least, plain
from grt.policies.rsl_rl import load_checkpoint
from grt.redteam import episode_seeds
from grt.report import figures
from grt.scores import ScoreSpec
from grt.swapcheck import check_settings, not_checked, swap_check
from grt.targets import check_target

log = logging.getLogger("grt.blueteam")

#: a red-team run from a config: ``run(cfg) -> summary`` (the ``python -m grt.run`` library function).
RedTeam = Callable[[DictConfig], dict]


def blueteam(cfg: DictConfig, out_dir: Path, red_team: RedTeam | None = None) -> dict:
    """Run one blue-team study (see the module docstring); returns ``{"rows": [...], ...}``.

    Args:
        cfg: the ``blueteam`` app's config (``run``, ``blueteam``, ``workers``, ``evaluator``, ``paths``).
        out_dir: the study's folder.
        red_team: runs the re-red-team (``blueteam.rered.enabled``); the app passes GRT's red-team run.

    Raises:
        BlueTeamError: settings or a run that cannot be blue-teamed (one line in the app).
    """
    bt = cfg.blueteam
    _check(bt, red_team)
    run_dir = Path(cfg.run)
    run_cfg, records = load_run(run_dir)
    for key, node in (("policy", run_cfg.get("policy")), ("task.session", run_cfg.task.get("session"))):
        if node is not None and "_target_" in node:  # a class that no longer imports is one line
            check_target(key, node)
    task, policy_cfg = plain(run_cfg.task), plain(run_cfg.policy)
    checkpoint = trainable_checkpoint(policy_cfg)
    ckpt = load_checkpoint(checkpoint)
    nominal, crash, heldout = _geometries(cfg, run_cfg, run_dir, records)
    swap = _swap_check(cfg, run_cfg, task, policy_cfg, nominal, records)
    log.info("blue-teaming %s: %d CrashShape(s) %s, %d held-out shapes", checkpoint, len(crash),
             [g.name for g in crash], len(heldout))

    seed = int(run_cfg.budget.seed)
    test_seeds = episode_seeds(seed + 1000, int(bt.eval_trials))
    val_seeds = episode_seeds(seed + 2000, max(int(bt.val_trials), int(bt.val_trials_nominal or bt.val_trials)))
    confirm_seeds = episode_seeds(seed + 3000, int(bt.confirm.trials))
    everything = [nominal, *crash, *heldout]
    scores = _Scores(out_dir / "scores.json", everything, test_seeds, cfg)
    before = scores.get("before", task, policy_cfg)
    fine_tuned = fine_tune(cfg, out_dir, task, policy_cfg, ckpt, checkpoint, [nominal, *crash], val_seeds,
                           confirm_seeds)
    after = scores.get("after", task, {**policy_cfg, "checkpoint": str(fine_tuned)})

    rows = _table_rows(Path(checkpoint).stem, crash, heldout, before, after, int(bt.eval_trials))
    write_table(out_dir, rows, ScoreSpec.from_task(run_cfg.task))
    result = {"run": str(run_dir), "checkpoint": str(fine_tuned), "rows": rows,
              "heldout": [g.name for g in heldout], "swap_check": swap}
    if bt.rered.enabled:
        result["rered"] = rered(run_cfg, run_dir, fine_tuned, out_dir / "rered", red_team, cfg.evaluator)
    (out_dir / "blueteam.json").write_text(json.dumps(result, indent=1, default=str))
    return result


def _swap_check(cfg: DictConfig, run_cfg: DictConfig, task: dict, policy: dict, nominal: Geometry,
                records: list[dict]) -> dict:
    """The swap check of the run's task (:mod:`grt.swapcheck`) on the run's nominal episodes, with the study's
    ``swap_check`` settings: cached from the red-team run, or only the stock actor runs (the journal holds the
    nominal's trials). A disagreeing swap stops the study before any training (one line, exit code 2)."""
    settings = SwapCheckSettings.from_config(cfg.get("swap_check"))
    check_settings(task, run_cfg.object, settings)
    seeds = episode_seeds(int(run_cfg.budget.seed), int(run_cfg.budget.trials))
    args = (task, policy, str(run_cfg.object), nominal.mesh, seeds)
    rest = (settings, cfg.paths.cache_dir, plain(run_cfg.evaluator), next(r for r in records if r["iteration"] == 0))
    if not_checked(task, str(run_cfg.object)) is not None or not settings.enabled:
        swap, _ = swap_check(*args, None, *rest)  # recorded as not checked; no evaluator needed
    else:
        with make_evaluator(cfg, task, policy) as ev:  # its workers start only if the stock actor must run
            swap, _ = swap_check(*args, ev, *rest)
    log.info("%s", figures.swap_line({"swap_check": swap}))
    return swap


def _check(bt: DictConfig, red_team: RedTeam | None) -> None:
    """Refuse settings that cannot work, before any simulation."""
    check_guard(str(bt.nominal_guard))
    ints = {"iterations": 1, "top_k": 1, "num_envs": 1, "num_steps_per_env": 1, "max_steps": 1, "eval_trials": 1,
            "val_trials": 1, "val_interval": 1, "val_patience": 1}
    for key, low in ints.items():
        if not at_least(low).check(bt.get(key)):
            raise BlueTeamError(f"blueteam.{key}={bt.get(key)}: give {at_least(low).accepts}")
    share, below = bt.get("nominal_share"), bt.get("failing_below")
    if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0.0 <= float(share) < 1.0:
        raise BlueTeamError(f"blueteam.nominal_share={share}: give a number in [0, 1) (the fraction of training "
                            "episodes on the nominal object; the rest are on the CrashShapes)")
    if isinstance(below, bool) or not isinstance(below, (int, float)) or not 0.0 < float(below) <= 1.0:
        raise BlueTeamError(f"blueteam.failing_below={below}: give a number in (0, 1] (a CrashShape scores below "
                            "this fraction of S0)")
    if int(bt.confirm.candidates) < 0 or (int(bt.confirm.candidates) > 0 and int(bt.confirm.trials) < 1):
        raise BlueTeamError(f"blueteam.confirm: candidates={bt.confirm.candidates}, trials={bt.confirm.trials} "
                            "cannot confirm: give candidates >= 1 and trials >= 1, or candidates=0 to export "
                            "the best validation unconfirmed")
    if bt.rered.enabled and red_team is None:
        raise BlueTeamError("blueteam.rered.enabled=true needs a red-team runner (red_team=...); "
                            "or set blueteam.rered.enabled=false")


def _geometries(cfg: DictConfig, run_cfg: DictConfig, run_dir: Path, records: list[dict]):
    """``(nominal, CrashShapes, held-out shapes)`` of the study, each mesh re-made from the run's journal."""
    bt = cfg.blueteam
    nominal, deformer, collision = run_geometry(run_cfg, run_dir, cfg.paths.cache_dir)
    s0 = float(next(r["score"] for r in records if r["iteration"] == 0))
    train_recs = select_crashshapes(records, bt.crashshapes, bt.top_k, bt.failing_below, s0)
    failing = failing_records(records, bt.failing_below, s0)  # held-out: failing ones not trained on
    held_recs = distinct(failing, train_recs, bt.heldout.candidates)

    def geometry(rec, role, theta=None, name=None):
        mesh = deformer.meshes(np.asarray(rec["theta"] if theta is None else theta)[None])[0]
        return Geometry(name or name_of(rec), mesh, collision.parts(mesh), role, rec.get("score"))

    crash = [geometry(r, "crashshape") for r in train_recs]
    nominal_geo = Geometry("nominal", nominal, collision.parts(nominal), "nominal", s0)
    rng = np.random.default_rng(int(bt.seed))
    nearby = [geometry(r, "heldout", np.asarray(r["theta"]) + rng.normal(0.0, bt.heldout.sigma,
                                                                          np.shape(r["theta"])),
                       f"near_{name_of(r)}_{j}")
              for r in train_recs for j in range(bt.heldout.nearby)]
    heldout = [geometry(r, "heldout") for r in held_recs] + nearby
    return nominal_geo, crash, heldout


class _Scores:
    """``scores.json``: every geometry's score and per-trial outcomes on the same seeds, ``before`` and
    ``after`` the fine-tune; a side already scored (a resumed study) is read back, not simulated."""

    def __init__(self, path: Path, geometries: list[Geometry], seeds: list[int], cfg: DictConfig):
        self.path, self.geometries, self.seeds, self.cfg = path, geometries, seeds, cfg
        self.data = json.loads(path.read_text()) if path.exists() else {}

    def get(self, side: str, task: dict, policy: dict) -> dict:
        if side not in self.data:
            with make_evaluator(self.cfg, task, policy) as ev:
                results = ev.evaluate([g.mesh for g in self.geometries], self.seeds,
                                      parts=[g.parts for g in self.geometries])
            self.data[side] = {g.name: {"score": r.score, "role": g.role, "outcomes": r.outcomes}
                               for g, r in zip(self.geometries, results, strict=True)}
            self.path.write_text(json.dumps(self.data, indent=1))
        return self.data[side]


def _table_rows(policy: str, crash: list[Geometry], heldout: list[Geometry], before: dict, after: dict,
                trials: int) -> list[dict]:
    """Table 3's rows: one per CrashShape, with the nominal object's and the held-out shapes' scores."""
    def mean(side: dict, geos: list[Geometry]) -> float:
        return float(np.mean([side[g.name]["score"] for g in geos])) if geos else float("nan")

    label = "joint" if len(crash) > 1 else crash[0].name
    return [{"policy": policy, "geometry": g.name, "fine_tune": label,
             "orig": before[g.name]["score"], "blue": after[g.name]["score"],
             "nominal_before": before["nominal"]["score"], "nominal_after": after["nominal"]["score"],
             "heldout_before": mean(before, heldout), "heldout_after": mean(after, heldout),
             "red_team_score": g.red_team_score, "trials": trials} for g in crash]


def rered(run_cfg: DictConfig, run_dir: Path, checkpoint: Path, out: Path, red_team: RedTeam,
          evaluator: DictConfig | None = None) -> dict:
    """A red-team run against the fine-tuned policy with the original budget and seed.

    ``evaluator``: the blue-team's evaluator config (:func:`rered_config`); ``None`` keeps the run's.
    """
    cfg = rered_config(run_cfg, checkpoint, out, evaluator)
    original = json.loads((run_dir / "summary.json").read_text()) if (run_dir / "summary.json").exists() else {}
    start = time.perf_counter()
    summary = red_team(cfg)
    keys = ("s0", "best_score", "final_drop", "iter_at_50", "reached_50", "auc")
    return {"before": {k: original.get(k) for k in keys}, "after": {k: summary.get(k) for k in keys},
            "wall_s": round(time.perf_counter() - start, 1), "folder": str(out)}


#: evaluator keys a candidate's trials depend on (its collision parts): a re-red-team keeps the run's
SEARCH_EVALUATOR_KEYS = ("collision", "coacd", "max_hull_vertices")


def rered_config(run_cfg: DictConfig, checkpoint: Path, out: Path, evaluator: DictConfig | None = None) -> DictConfig:
    """The re-red-team's config: the red-team run's own (budget, seed, search), the fine-tuned policy, a
    new folder, and the blue-team's evaluator (``evaluator``, the app's ``evaluator`` node: its backend,
    e.g. a Ray cluster, and its workers), but the run's collision settings
    (:data:`SEARCH_EVALUATOR_KEYS`): neither the backend nor the number of workers changes a result."""
    cfg = OmegaConf.create(OmegaConf.to_container(run_cfg, resolve=False))
    cfg.policy.checkpoint = str(checkpoint)
    cfg.paths.output_dir = str(out)
    cfg.resume = None
    if evaluator is not None:
        ev = OmegaConf.to_container(evaluator, resolve=True)
        own = OmegaConf.to_container(run_cfg.evaluator, resolve=False)
        ev.update({k: own[k] for k in SEARCH_EVALUATOR_KEYS if k in own})
        cfg.evaluator = ev
        cfg.budget.workers = ev["workers"]
    return cfg
