"""The blue-team fine-tune: PPO on a mix of the nominal object and CrashShapes, early-stopped by the
nominal guard, the best validated checkpoints confirmed on fresh episodes (resumable).

:func:`fine_tune` writes ``policy.pt`` (the chosen checkpoint, exported), ``last.pt`` / ``val_best.pt``
(training), ``metrics.csv`` / ``curve.png``, the guard's files (:mod:`grt.blueteam.guard`),
``confirm.json`` and ``validation.png``.
"""

from __future__ import annotations

import contextlib
import copy
import json
import logging
from pathlib import Path

import torch

from grt.blueteam.core import Geometry, choose_confirmed, plot_validation, rank_candidates
from grt.blueteam.guard import GuardRule, NominalGuard, episodes, read_rows
from grt.blueteam.spec import StudySpec
from grt.policies.rsl_rl import RslRlPolicy
from grt.rl.anchor import NominalAnchor
from grt.rl.train import TrainSpec, ValidationSpec, export_policy, plot_curve, train
from grt.rl.vec_env import Shape, TaskVecEnv

log = logging.getLogger("grt.blueteam")
# entries of the starting checkpoint's ``grt`` config that the fine-tune's own checkpoints write anew
_OWN_KEYS = ("train_cfg", "task_cfg", "obs_spec", "num_actions", "task")


def fine_tune(spec: StudySpec, out_dir: Path, task: dict, policy: dict, ckpt: dict, checkpoint: str,
              shapes: list[Geometry], val_seeds: list[int], confirm_seeds: list[int], evaluator) -> Path:
    """PPO on the mix (resumable), early-stopped on validation episodes, the best validated checkpoints
    confirmed on fresh episodes; returns the policy file.

    Args:
        spec: the study's settings (``blueteam.*``, ``workers``).
        task, policy: the red-team run's task and policy configs (plain).
        ckpt, checkpoint: the starting policy's checkpoint dict and its path.
        shapes: the nominal object first, then the CrashShapes trained on.
        val_seeds, confirm_seeds: validation and confirmation episode seeds.
        evaluator: the study's evaluator (:func:`grt.blueteam.core.make_evaluator`, ``evaluator=sim|ray``): the
            validation and confirmation episodes run on its workers, each checkpoint swapped in; its workers
            stay idle while PPO collects. Shown without progress bars (PPO's own shows).
    """
    policy_file = out_dir / "policy.pt"
    if policy_file.exists():
        return policy_file
    share = spec.nominal_share
    weights = [share] + [(1.0 - share) / (len(shapes) - 1)] * (len(shapes) - 1)
    env = TaskVecEnv(task, [Shape.of(g.mesh, g.parts, g.name) for g in shapes], num_envs=spec.num_envs,
                     workers=spec.workers, seed=spec.seed, weights=weights, max_steps=spec.max_steps)
    anchor = make_anchor(spec, task, checkpoint, shapes[0])
    rule = GuardRule.of(spec, task)
    guard = NominalGuard(out_dir, policy, shapes, val_seeds, evaluator, rule, spec.val_trials,
                         spec.val_trials_nominal, spec.confirm.candidates)
    training = TrainSpec(
        _train_cfg(spec, ckpt), out_dir, task["name"], task, iterations=spec.iterations, init_checkpoint=checkpoint,
        save_interval=5, anchor=anchor,
        extra={**{k: v for k, v in ckpt["grt"].items() if k not in _OWN_KEYS},
               "blueteam": {"from": checkpoint, "shapes": [g.name for g in shapes], "weights": weights}},
        validation=ValidationSpec(guard, interval=spec.val_interval, patience=spec.val_patience,
                                  perfect=1.0 if rule.binary else None, restart=guard.restart))
    with _without_progress(evaluator):
        try:
            result = train(env, training)
        finally:
            env.close()
        # the confirmation swaps the candidates into the validation's workers: no new pool per candidate
        best = confirm(out_dir, policy, shapes, rule, confirm_seeds, evaluator, spec.confirm.candidates)
    plot_curve(out_dir / "metrics.csv", out_dir / "curve.png", title="blue-team fine-tune")
    if best is None:  # no confirmation asked for (confirm.candidates=0), or nothing validated
        best = out_dir / ("val_best.pt" if (out_dir / "val_best.pt").exists() else "last.pt")
    if guard.detail.exists():
        chosen = int(torch.load(best, map_location="cpu", weights_only=False).get("iter", -2)) + 1
        plot_validation(read_rows(guard.detail), out_dir / "validation.png", str(task.get("score", "success")), chosen)
    return export_policy(best, policy_file, metrics={k: v for k, v in result.items() if k != "validation"})


@contextlib.contextmanager
def _without_progress(evaluator):
    """``evaluator`` showing no progress bar (the validation's episodes run inside PPO's bar), then as it was."""
    shown = getattr(evaluator, "progress", False)
    evaluator.progress = False
    try:
        yield evaluator
    finally:
        evaluator.progress = shown


def _train_cfg(spec: StudySpec, ckpt: dict) -> dict:
    """The starting checkpoint's PPO settings with the fine-tune's overrides."""
    train_cfg = copy.deepcopy(ckpt["grt"]["train_cfg"])
    train_cfg["algorithm"].update(copy.deepcopy(spec.algorithm))
    train_cfg["num_steps_per_env"] = spec.num_steps_per_env
    # The policy's weights were fitted under its observation statistics; updating them from CrashShape
    # rollouts would shift every input the nominal object gives it (measured: up to 1.4x in a std, 0.3 std
    # in a mean within 30 iterations, and the nominal plug regressed from the first validation).
    train_cfg["freeze_normalization"] = spec.freeze_normalization
    return train_cfg


def make_anchor(spec: StudySpec, task: dict, checkpoint: str, nominal: Geometry) -> NominalAnchor | None:
    """The starting policy's actions on its own nominal-object states (``blueteam.anchor``; ``None``: off)."""
    a = spec.anchor
    if a.updates <= 0:
        return None
    reference = RslRlPolicy(checkpoint, task=task["name"]).actor  # the policy before fine-tuning, on resume too
    env = TaskVecEnv(task, [Shape.of(nominal.mesh, nominal.parts, nominal.name)], num_envs=a.envs,
                     workers=spec.workers, seed=spec.seed + 1, max_steps=spec.max_steps)
    try:
        anchor = NominalAnchor.record(reference, env, steps=a.steps, noise=a.noise, seed=spec.seed,
                                      updates=a.updates, lr=float(spec.algorithm["learning_rate"]))
    finally:
        env.close()
    log.info("anchor: %d nominal states of the starting policy, %d steps per PPO iteration", len(anchor.targets),
             anchor.updates)
    return anchor


def confirm(out_dir: Path, policy: dict, shapes: list[Geometry], rule: GuardRule, seeds: list[int], evaluator,
            candidates: int) -> Path | None:
    """Re-score the ``candidates`` best validated checkpoints on fresh episodes and choose among them on
    validation and confirmation pooled (:func:`grt.blueteam.core.choose_confirmed`); writes
    ``confirm.json`` and returns the chosen checkpoint (``None``: nothing to confirm). Resumable: episodes
    already scored are kept in ``confirm.json``."""
    detail = out_dir / "validation.jsonl"
    if candidates <= 0 or not detail.exists():
        return None
    top = [r for r in rank_candidates(read_rows(detail), candidates)
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
        fresh["start"] = episodes(policy, nominal, seeds, evaluator)
        state_file.write_text(json.dumps(state, indent=1))
    for r in top:
        key = f"it{r['iteration']}"
        if key not in fresh:
            log.info("confirming the checkpoint of iteration %d on %d fresh episodes", r["iteration"], len(seeds))
            fresh[key] = episodes({**policy, "checkpoint": str(out_dir / "candidates" / f"{key}.pt")},
                                  shapes, seeds, evaluator)
            state_file.write_text(json.dumps(state, indent=1))
    start = json.loads((out_dir / "val_nominal.json").read_text())
    pooled = [{"iteration": r["iteration"], "nominal": r["episodes"]["nominal"] + fresh[f"it{r['iteration']}"]["nominal"],
               "crashshapes": {k: v + fresh[f"it{r['iteration']}"][k] for k, v in r["episodes"].items()
                               if k != "nominal"}} for r in top]
    pick, table = choose_confirmed(pooled, start["scores"] + fresh["start"]["nominal"], rule.guard,
                                   rule.tolerance, rule.alpha, rule.binary)
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
