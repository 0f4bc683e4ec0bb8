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

The study reads its settings from a :class:`grt.blueteam.spec.StudySpec` (the app's config, parsed and checked
once) and the red-team run's from its :class:`grt.plan.RunPlan` (:func:`grt.blueteam.core.load_run`).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from grt.blueteam.core import (
    BlueTeamError,
    Geometry,
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
from grt.blueteam.spec import StudySpec
from grt.plan import RunPlan
from grt.policies.rsl_rl import load_checkpoint
from grt.redteam import episode_seeds
from grt.report import figures
from grt.swapcheck import check_settings, not_checked, swap_check
from grt.targets import check_target

log = logging.getLogger("grt.blueteam")

#: the re-red-team: ``red_team(run, checkpoint, out) -> summary``, a red-team run of the fine-tuned policy
#: ``checkpoint`` in the folder ``out`` with the budget and seed of the run (its plan); the app passes one
#: that makes its config (:func:`grt.cli.blueteam.rered_config`) and runs it (:func:`grt.runner.run`).
RedTeam = Callable[[RunPlan, Path, Path], dict]


def blueteam(spec: StudySpec, out_dir: Path, red_team: RedTeam | None = None) -> dict:
    """Run one blue-team study (see the module docstring); returns ``{"rows": [...], ...}``.

    Args:
        spec: the study's settings (the ``blueteam`` app's config, checked).
        out_dir: the study's folder.
        red_team: runs the re-red-team (``blueteam.rered.enabled``); the app passes GRT's red-team run.

    Raises:
        BlueTeamError: a run that cannot be blue-teamed (one line in the app).
    """
    if spec.rered and red_team is None:
        raise BlueTeamError("blueteam.rered.enabled=true needs a red-team runner (red_team=...); "
                            "or set blueteam.rered.enabled=false")
    run, records = load_run(spec.run)
    for key, node in (("policy", run.policy), ("task.session", run.task.get("session"))):
        if node is not None and "_target_" in node:  # a class that no longer imports is one line
            check_target(key, node)
    task, policy_cfg = run.task, run.policy
    checkpoint = trainable_checkpoint(policy_cfg)
    ckpt = load_checkpoint(checkpoint)
    nominal, crash, heldout = _geometries(spec, run, records)
    swap = _swap_check(spec, run, nominal, records)
    log.info("blue-teaming %s: %d CrashShape(s) %s, %d held-out shapes", checkpoint, len(crash),
             [g.name for g in crash], len(heldout))

    seed = run.budget.seed
    test_seeds = episode_seeds(seed + 1000, spec.eval_trials)
    val_seeds = episode_seeds(seed + 2000, max(spec.val_trials, spec.val_trials_nominal))
    confirm_seeds = episode_seeds(seed + 3000, spec.confirm.trials)
    everything = [nominal, *crash, *heldout]
    scores = _Scores(out_dir / "scores.json", everything, test_seeds)
    # one evaluator for the scores, the validation and the confirmation: its workers start at its first episodes
    # (none when a resumed study has them all), and each policy after the first is swapped into them
    with make_evaluator(spec.evaluator, task, policy_cfg) as ev:
        before = scores.get("before", ev)
        fine_tuned = fine_tune(spec, out_dir, task, policy_cfg, ckpt, checkpoint, [nominal, *crash], val_seeds,
                               confirm_seeds, ev)
        after = scores.get("after", ev, {**policy_cfg, "checkpoint": str(fine_tuned)})

    rows = _table_rows(Path(checkpoint).stem, crash, heldout, before, after, spec.eval_trials)
    write_table(out_dir, rows, run.score)
    result = {"run": str(spec.run), "checkpoint": str(fine_tuned), "rows": rows,
              "heldout": [g.name for g in heldout], "swap_check": swap}
    if spec.rered:
        result["rered"] = rered(run, fine_tuned, out_dir / "rered", red_team)
    (out_dir / "blueteam.json").write_text(json.dumps(result, indent=1, default=str))
    return result


def _swap_check(spec: StudySpec, run: RunPlan, nominal: Geometry, records: list[dict]) -> dict:
    """The swap check of the run's task (:mod:`grt.swapcheck`) on the run's nominal episodes, with the study's
    ``swap_check`` settings: cached from the red-team run, or only the stock actor runs (the journal holds the
    nominal's trials). A disagreeing swap stops the study before any training (one line, exit code 2)."""
    task, policy, settings = run.task, run.policy, spec.swap_check
    check_settings(task, run.object, settings)
    seeds = episode_seeds(run.budget.seed, run.budget.trials)
    args = (task, policy, run.object, nominal.mesh, seeds)
    rest = (settings, spec.cache_dir, run.evaluator, next(r for r in records if r["iteration"] == 0))
    if not_checked(task, run.object) is not None or not settings.enabled:
        swap, _ = swap_check(*args, None, *rest)  # recorded as not checked; no evaluator needed
    else:
        with make_evaluator(spec.evaluator, task, policy) as ev:  # its workers start only if the stock actor runs
            swap, _ = swap_check(*args, ev, *rest)
    log.info("%s", figures.swap_line({"swap_check": swap}))
    return swap


def _geometries(spec: StudySpec, run: RunPlan, records: list[dict]):
    """``(nominal, CrashShapes, held-out shapes)`` of the study, each mesh re-made from the run's journal."""
    nominal, deformer, collision = run_geometry(run, spec.cache_dir)
    s0 = float(next(r["score"] for r in records if r["iteration"] == 0))
    train_recs = select_crashshapes(records, spec.crashshapes, spec.top_k, spec.failing_below, s0)
    failing = failing_records(records, spec.failing_below, s0)  # held-out: failing ones not trained on
    held_recs = distinct(failing, train_recs, spec.heldout.candidates)

    def geometry(rec, role, theta=None, name=None):
        mesh = deformer.meshes(np.asarray(rec["theta"] if theta is None else theta)[None])[0]
        return Geometry(name or name_of(rec), mesh, collision.parts(mesh), role, rec.get("score"))

    crash = [geometry(r, "crashshape") for r in train_recs]
    nominal_geo = Geometry("nominal", nominal, collision.parts(nominal), "nominal", s0)
    rng = np.random.default_rng(spec.seed)
    nearby = [geometry(r, "heldout", np.asarray(r["theta"]) + rng.normal(0.0, spec.heldout.sigma,
                                                                          np.shape(r["theta"])),
                       f"near_{name_of(r)}_{j}")
              for r in train_recs for j in range(spec.heldout.nearby)]
    heldout = [geometry(r, "heldout") for r in held_recs] + nearby
    return nominal_geo, crash, heldout


class _Scores:
    """``scores.json``: every geometry's score and per-trial outcomes on the same seeds, ``before`` and
    ``after`` the fine-tune; a side already scored (a resumed study) is read back, not simulated."""

    def __init__(self, path: Path, geometries: list[Geometry], seeds: list[int]):
        self.path, self.geometries, self.seeds = path, geometries, seeds
        self.data = json.loads(path.read_text()) if path.exists() else {}

    def get(self, side: str, evaluator, policy: dict | None = None) -> dict:
        """The scores of ``side``, simulated on ``evaluator`` with ``policy`` swapped in (``None``: its own)
        unless ``scores.json`` has them."""
        if side not in self.data:
            results = evaluator.evaluate([g.mesh for g in self.geometries], self.seeds,
                                         parts=[g.parts for g in self.geometries], policy=policy)
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


def rered(run: RunPlan, checkpoint: Path, out: Path, red_team: RedTeam) -> dict:
    """A red-team run against the fine-tuned policy with the original budget and seed (``red_team``), and its
    figures beside the original run's (its ``summary.json``)."""
    summary_file = run.run_dir / "summary.json"
    original = json.loads(summary_file.read_text()) if summary_file.exists() else {}
    start = time.perf_counter()
    summary = red_team(run, checkpoint, out)
    keys = ("s0", "best_score", "final_drop", "iter_at_50", "reached_50", "auc")
    return {"before": {k: original.get(k) for k in keys}, "after": {k: summary.get(k) for k in keys},
            "wall_s": round(time.perf_counter() - start, 1), "folder": str(out)}
