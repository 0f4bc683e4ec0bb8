"""``python -m grt.blueteam run=<red-team run folder>``: fine-tune the run's policy on its CrashShapes.

Writes into its own folder (``outputs/blueteam/<task>/<object>/<time>``): ``policy.pt`` (the
fine-tuned checkpoint, config inside), ``metrics.csv`` and ``curve.png`` (training),
``validation.json`` / ``validation.jsonl`` / ``validation.png`` (early stopping), ``confirm.json`` (the
best validated checkpoints, kept in ``candidates/``, re-scored on fresh episodes; the exported one is
chosen on validation and confirmation pooled), ``scores.json`` (every geometry before and after, per trial),
``table3.json`` / ``table3.md`` (the paper's Table 3 columns plus held-out shapes) and, with
``blueteam.rered.enabled``, a re-red-team run of the fine-tuned policy under ``rered/`` with the
original run's budget and seed. ``resume=<that folder>`` continues a killed fine-tune.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import hydra
import numpy as np
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

import grt.config  # noqa: F401 - schemas and resolvers

log = logging.getLogger("grt.blueteam")


def _plain(node) -> dict:
    return OmegaConf.to_container(node, resolve=True)


def blueteam(cfg: DictConfig, out_dir: Path) -> dict:
    """Run one blue-team study (see the module docstring); returns ``{"rows": [...], ...}``."""
    from grt.blueteam.core import (
        BlueTeamError,
        Geometry,
        check_guard,
        distinct,
        failing_records,
        load_run,
        name_of,
        run_geometry,
        select_crashshapes,
        trainable_checkpoint,
        write_table,
    )
    from grt.policies.rsl_rl import load_checkpoint
    from grt.redteam import episode_seeds
    from grt.scores import ScoreSpec

    bt = cfg.blueteam
    check_guard(str(bt.nominal_guard))
    if int(bt.confirm.candidates) < 0 or (int(bt.confirm.candidates) > 0 and int(bt.confirm.trials) < 1):
        raise BlueTeamError(f"blueteam.confirm: candidates={bt.confirm.candidates}, trials={bt.confirm.trials} "
                            "cannot confirm: give candidates >= 1 and trials >= 1, or candidates=0 to export "
                            "the best validation unconfirmed")
    run_dir = Path(cfg.run)
    run_cfg, records = load_run(run_dir)
    task, policy_cfg = _plain(run_cfg.task), _plain(run_cfg.policy)
    checkpoint = trainable_checkpoint(policy_cfg)
    ckpt = load_checkpoint(checkpoint)
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
    log.info("blue-teaming %s: %d CrashShape(s) %s, %d held-out shapes", checkpoint, len(crash),
             [g.name for g in crash], len(heldout))

    test_seeds = episode_seeds(int(run_cfg.budget.seed) + 1000, int(bt.eval_trials))
    val_seeds = episode_seeds(int(run_cfg.budget.seed) + 2000,
                              max(int(bt.val_trials), int(bt.val_trials_nominal or bt.val_trials)))
    everything = [nominal_geo, *crash, *heldout]
    scores_file = out_dir / "scores.json"
    scores = json.loads(scores_file.read_text()) if scores_file.exists() else {}
    if "before" not in scores:
        scores["before"] = _score(task, policy_cfg, everything, test_seeds, cfg.workers)
        scores_file.write_text(json.dumps(scores, indent=1))

    confirm_seeds = episode_seeds(int(run_cfg.budget.seed) + 3000, int(bt.confirm.trials))
    fine_tuned = _fine_tune(cfg, out_dir, task, policy_cfg, ckpt, checkpoint, [nominal_geo, *crash], val_seeds,
                            confirm_seeds)
    after_policy = {**policy_cfg, "checkpoint": str(fine_tuned)}
    if "after" not in scores:
        scores["after"] = _score(task, after_policy, everything, test_seeds, cfg.workers)
        scores_file.write_text(json.dumps(scores, indent=1))

    before, after = scores["before"], scores["after"]
    mean = lambda side, geos: float(np.mean([side[g.name]["score"] for g in geos])) if geos else float("nan")  # noqa: E731
    label = "joint" if len(crash) > 1 else crash[0].name
    rows = [{"policy": Path(checkpoint).stem, "geometry": g.name, "fine_tune": label,
             "orig": before[g.name]["score"], "blue": after[g.name]["score"],
             "nominal_before": before["nominal"]["score"], "nominal_after": after["nominal"]["score"],
             "heldout_before": mean(before, heldout), "heldout_after": mean(after, heldout),
             "red_team_score": g.red_team_score, "trials": int(bt.eval_trials)} for g in crash]
    write_table(out_dir, rows, ScoreSpec.from_task(run_cfg.task))
    result = {"run": str(run_dir), "checkpoint": str(fine_tuned), "rows": rows,
              "heldout": [g.name for g in heldout]}
    if bt.rered.enabled:
        result["rered"] = _rered(run_cfg, run_dir, fine_tuned, out_dir / "rered")
    (out_dir / "blueteam.json").write_text(json.dumps(result, indent=1, default=str))
    return result


def _score(task: dict, policy: dict, geometries, seeds: list[int], workers: int) -> dict:
    """Every geometry's score and per-trial outcomes on the same seeds."""
    from grt.evaluators.sim import SimEvaluator

    with SimEvaluator(task=task, policy=policy, workers=workers, collision="coacd", progress=True) as ev:
        results = ev.evaluate([g.mesh for g in geometries], seeds, parts=[g.parts for g in geometries])
    return {g.name: {"score": r.score, "role": g.role, "outcomes": r.outcomes} for g, r in zip(geometries, results,
                                                                                             strict=True)}


def _fine_tune(cfg: DictConfig, out_dir: Path, task: dict, policy: dict, ckpt: dict, checkpoint: str, shapes,
               val_seeds: list[int], confirm_seeds: list[int]) -> Path:
    """PPO on the mix (resumable), early-stopped on validation episodes, the best validated checkpoints
    confirmed on fresh episodes; returns the policy file."""
    import copy

    import torch

    from grt.blueteam.core import nominal_regressed, plot_validation
    from grt.evaluators.sim import SimEvaluator
    from grt.rl.train import export_policy, plot_curve, train
    from grt.rl.vec_env import Shape, TaskVecEnv

    bt = cfg.blueteam
    policy_file = out_dir / "policy.pt"
    if policy_file.exists():
        return policy_file
    train_cfg = copy.deepcopy(ckpt["grt"]["train_cfg"])
    train_cfg["algorithm"].update(_plain(bt.algorithm))
    train_cfg["num_steps_per_env"] = int(bt.num_steps_per_env)
    # The policy's weights were fitted under its observation statistics; updating them from CrashShape
    # rollouts would shift every input the nominal object gives it (measured: up to 1.4x in a std, 0.3 std
    # in a mean within 30 iterations, and the nominal plug regressed from the first validation).
    train_cfg["freeze_normalization"] = bool(bt.freeze_normalization)
    share = float(bt.nominal_share)
    weights = [share] + [(1.0 - share) / (len(shapes) - 1)] * (len(shapes) - 1)
    env = TaskVecEnv(task, [Shape.of(g.mesh, g.parts, g.name) for g in shapes], num_envs=bt.num_envs,
                     workers=cfg.workers, seed=int(bt.seed), weights=weights, max_steps=bt.max_steps)
    anchor = _anchor(cfg, task, checkpoint, shapes[0])
    # validation episodes run on their own workers (idle while PPO collects), two at a time on 2 cores
    evaluator = SimEvaluator(task=task, policy=policy, workers=cfg.workers, collision="coacd", progress=False)

    guard = out_dir / "val_nominal.json"  # the nominal object's validation episodes before fine-tuning
    rule = {"guard": str(bt.nominal_guard), "tolerance": float(bt.nominal_tolerance),
            "alpha": float(bt.nominal_alpha), "binary": str(task.get("score", "success")) == "success"}
    n_crash, n_nominal = int(bt.val_trials), int(bt.val_trials_nominal or bt.val_trials)
    detail = out_dir / "validation.jsonl"

    def validate(path: Path) -> float:
        """The CrashShapes' mean validation score, for a checkpoint whose nominal validation shows no
        regression from the start (``nominal_guard``); one that does ranks below every one that does not."""
        checkpoint_now = {**policy, "checkpoint": str(path)}  # the workers swap in each checkpoint
        per = _episodes(checkpoint_now, shapes[:1], val_seeds[:n_nominal], evaluator)
        per.update(_episodes(checkpoint_now, shapes[1:], val_seeds[:n_crash], evaluator))
        if not guard.exists():  # the first validation is of the policy before any update
            guard.write_text(json.dumps({"nominal": float(np.mean(per["nominal"])), "scores": per["nominal"],
                                         **rule}))
        start = json.loads(guard.read_text())
        crash = float(np.mean([np.mean(v) for k, v in per.items() if k != "nominal"]))
        if "scores" in start:
            regressed, why = nominal_regressed(start["scores"], per["nominal"], rule["guard"], rule["tolerance"],
                                               rule["alpha"], rule["binary"])
        else:  # a fine-tune started before the guard kept its episodes: its fixed tolerance
            regressed, why = nominal_regressed([start["nominal"]], [float(np.mean(per["nominal"]))], "tolerance",
                                               float(start.get("tolerance", rule["tolerance"])))
        log.info("validation: CrashShapes %.3f, nominal %.3f (%s: %s)", crash, float(np.mean(per["nominal"])), why,
                 "ranked below every kept checkpoint" if regressed else "kept")
        iteration = int(torch.load(path, map_location="cpu", weights_only=False).get("iter", -1)) + 1
        with detail.open("a") as f:  # one row per validation, for validation.png and the confirmation
            f.write(json.dumps({"iteration": iteration, "nominal": float(np.mean(per["nominal"])),
                                "crashshapes": {k: float(np.mean(v)) for k, v in per.items() if k != "nominal"},
                                "regressed": bool(regressed), "why": why, "episodes": per}) + "\n")
        _keep_candidate(out_dir, path, iteration, int(bt.confirm.candidates))
        return crash - 2.0 if regressed else crash

    try:
        result = train(env, train_cfg, out_dir, task["name"], task, iterations=int(bt.iterations),
                       init_checkpoint=checkpoint, save_interval=5,
                       extra={**{k: v for k, v in ckpt["grt"].items() if k not in ("train_cfg", "task_cfg",
                                                                                   "obs_spec", "num_actions",
                                                                                   "task")},
                              "blueteam": {"from": checkpoint, "shapes": [g.name for g in shapes],
                                           "weights": weights}},
                       validate=validate, val_interval=int(bt.val_interval), val_patience=int(bt.val_patience),
                       val_perfect=1.0 if str(task.get("score", "success")) == "success" else None,
                       anchor=anchor)
    finally:
        env.close()
    try:  # the confirmation swaps the candidates into the validation's workers: no new pool per candidate
        best = _confirm(cfg, out_dir, task, policy, shapes, rule, confirm_seeds, evaluator)
    finally:
        evaluator.close()
    plot_curve(out_dir / "metrics.csv", out_dir / "curve.png", title="blue-team fine-tune")
    if best is None:  # no confirmation asked for (confirm.candidates=0), or nothing validated
        best = out_dir / ("val_best.pt" if (out_dir / "val_best.pt").exists() else "last.pt")
    if detail.exists():
        rows = [json.loads(line) for line in detail.read_text().splitlines() if line.strip()]
        chosen = int(torch.load(best, map_location="cpu", weights_only=False).get("iter", -2)) + 1
        plot_validation(rows, out_dir / "validation.png", str(task.get("score", "success")), chosen)
    return export_policy(best, policy_file, metrics={k: v for k, v in result.items() if k != "validation"})


def _anchor(cfg: DictConfig, task: dict, checkpoint: str, nominal):
    """The starting policy's actions on its own nominal-object states (``blueteam.anchor``; ``None``: off)."""
    from grt.policies.rsl_rl import RslRlPolicy
    from grt.rl.anchor import NominalAnchor
    from grt.rl.vec_env import Shape, TaskVecEnv

    a = cfg.blueteam.anchor
    if int(a.updates) <= 0:
        return None
    reference = RslRlPolicy(checkpoint, task=task["name"]).actor  # the policy before fine-tuning, on resume too
    env = TaskVecEnv(task, [Shape.of(nominal.mesh, nominal.parts, nominal.name)], num_envs=int(a.envs),
                     workers=cfg.workers, seed=int(cfg.blueteam.seed) + 1, max_steps=cfg.blueteam.max_steps)
    try:
        anchor = NominalAnchor.record(reference, env, steps=int(a.steps), noise=float(a.noise),
                                      seed=int(cfg.blueteam.seed), updates=int(a.updates),
                                      lr=float(cfg.blueteam.algorithm.learning_rate))
    finally:
        env.close()
    log.info("anchor: %d nominal states of the starting policy, %d steps per PPO iteration", len(anchor.targets),
             anchor.updates)
    return anchor


def _keep_candidate(out_dir: Path, path: Path, iteration: int, keep: int) -> None:
    """Keep the checkpoint just validated as ``candidates/it<N>.pt`` while it ranks among the ``keep``
    best validated ones (see :func:`grt.blueteam.core.rank_candidates`); drop those it displaces."""
    import shutil

    from grt.blueteam.core import rank_candidates

    if keep <= 0:
        return
    rows = [json.loads(line) for line in (out_dir / "validation.jsonl").read_text().splitlines() if line.strip()]
    top = {f"it{r['iteration']}.pt" for r in rank_candidates(rows, keep)}
    folder = out_dir / "candidates"
    folder.mkdir(exist_ok=True)
    if f"it{iteration}.pt" in top:
        shutil.copyfile(path, folder / f"it{iteration}.pt")
    for f in folder.glob("it*.pt"):
        if f.name not in top:
            f.unlink()


def _confirm(cfg: DictConfig, out_dir: Path, task: dict, policy: dict, shapes, rule: dict,
             seeds: list[int], evaluator) -> Path | None:
    """Re-score the best validated checkpoints on fresh episodes and choose among them on validation and
    confirmation pooled (:func:`grt.blueteam.core.choose_confirmed`); writes ``confirm.json`` and
    returns the chosen checkpoint (``None``: nothing to confirm). Resumable: episodes already scored
    are kept in ``confirm.json``."""
    from grt.blueteam.core import choose_confirmed, rank_candidates

    bt = cfg.blueteam
    detail = out_dir / "validation.jsonl"
    if int(bt.confirm.candidates) <= 0 or not detail.exists():
        return None
    rows = [json.loads(line) for line in detail.read_text().splitlines() if line.strip()]
    top = [r for r in rank_candidates(rows, int(bt.confirm.candidates))
           if "episodes" in r and (out_dir / "candidates" / f"it{r['iteration']}.pt").exists()]
    if not top:
        return None
    state_file = out_dir / "confirm.json"
    state = json.loads(state_file.read_text()) if state_file.exists() else {}
    if state.get("seeds") != seeds:  # other fresh episodes (confirm.trials changed): score them anew
        state = {"seeds": seeds}
    fresh = state.setdefault("episodes", {})
    nominal = [g for g in shapes if g.name == "nominal"]
    if "start" not in fresh:  # the policy before fine-tuning on the same fresh nominal episodes
        fresh["start"] = _episodes(policy, nominal, seeds, evaluator)
        state_file.write_text(json.dumps(state, indent=1))
    for r in top:
        key = f"it{r['iteration']}"
        if key not in fresh:
            log.info("confirming the checkpoint of iteration %d on %d fresh episodes", r["iteration"], len(seeds))
            fresh[key] = _episodes({**policy, "checkpoint": str(out_dir / "candidates" / f"{key}.pt")},
                                   shapes, seeds, evaluator)
            state_file.write_text(json.dumps(state, indent=1))
    start = json.loads((out_dir / "val_nominal.json").read_text())
    pooled = [{"iteration": r["iteration"], "nominal": r["episodes"]["nominal"] + fresh[f"it{r['iteration']}"]["nominal"],
               "crashshapes": {k: v + fresh[f"it{r['iteration']}"][k] for k, v in r["episodes"].items()
                               if k != "nominal"}} for r in top]
    pick, table = choose_confirmed(pooled, start["scores"] + fresh["start"]["nominal"], rule["guard"],
                                   rule["tolerance"], rule["alpha"], rule["binary"])
    for r, t in zip(top, table, strict=True):
        t["validation"] = {"nominal": r["nominal"], "crashshapes": r["crashshapes"]}
    state.update({"seeds": seeds, "candidates": table, "chosen": table[pick]["iteration"]})
    state_file.write_text(json.dumps(state, indent=1))
    for t in table:
        log.info("confirmation, iteration %d: CrashShapes %.3f, nominal %.3f on validation + fresh episodes "
                 "(%s)%s", t["iteration"], t["crashshape_mean"], t["nominal"], t["why"],
                 ": chosen" if t["chosen"] else "")
    if not table[pick]["passed"]:
        log.warning("no validated checkpoint holds the nominal object on fresh episodes: iteration %d, the best "
                    "on the nominal object, is exported (confirm.json)", table[pick]["iteration"])
    return out_dir / "candidates" / f"it{table[pick]['iteration']}.pt"


def _episodes(policy: dict, geometries, seeds: list[int], evaluator) -> dict[str, list[float]]:
    """Each geometry's per-episode scores on ``seeds`` (simulator errors left out), on ``evaluator``'s
    workers with ``policy`` swapped in."""
    from grt.evaluators.base import SIM_ERROR

    results = evaluator.evaluate([g.mesh for g in geometries], seeds, parts=[g.parts for g in geometries],
                                 policy=policy)
    errors = sum(r.sim_errors for r in results)
    if errors:
        log.warning("%d of %d episodes ended in a simulator error and are left out", errors,
                    len(seeds) * len(geometries))
    return {g.name: [float(t.score) for t in r.trials if t.mode != SIM_ERROR]
            for g, r in zip(geometries, results, strict=True)}


def _rered(run_cfg: DictConfig, run_dir: Path, checkpoint: Path, out: Path) -> dict:
    """A red-team run against the fine-tuned policy with the original budget and seed."""
    from grt.runner import run

    cfg = OmegaConf.create(OmegaConf.to_container(run_cfg, resolve=False))
    cfg.policy.checkpoint = str(checkpoint)
    cfg.paths.output_dir = str(out)
    cfg.resume = None
    original = json.loads((run_dir / "summary.json").read_text()) if (run_dir / "summary.json").exists() else {}
    start = time.perf_counter()
    summary = run(cfg)
    keys = ("s0", "best_score", "final_drop", "iter_at_50", "reached_50", "auc")
    return {"before": {k: original.get(k) for k in keys}, "after": {k: summary.get(k) for k in keys},
            "wall_s": round(time.perf_counter() - start, 1), "folder": str(out)}


@hydra.main(config_path="../../conf", config_name="blueteam", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from grt.cli._common import exit_on_user_error

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    with exit_on_user_error():
        if cfg.run is None:
            from grt.blueteam.core import BlueTeamError

            raise BlueTeamError("give the red-team run to blue-team: python -m grt.blueteam run=<run folder>")
        result = blueteam(cfg, out_dir)
    print((out_dir / "table3.md").read_text())
    if "rered" in result:
        r = result["rered"]
        print(f"re-red-team: Final Drop {r['before']['final_drop']} -> {r['after']['final_drop']}, "
              f"Iter@50% {r['before']['iter_at_50']} -> {r['after']['iter_at_50']}")
    print(f"files in {out_dir}")


if __name__ == "__main__":
    from grt.cli._common import run_cli

    run_cli(main)
