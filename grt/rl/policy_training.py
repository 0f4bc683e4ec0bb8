"""Train a task's policy with PPO on its nominal object: what ``python -m grt.train`` runs.

The run folder gets ``metrics.csv`` (one row per PPO iteration), ``last.pt`` / ``best.pt`` (rsl-rl
checkpoints with the GRT config inside, resumable), ``curve.png`` (training curve), ``train.json``
(figures), with ``train.validation`` also ``val_best.pt`` (the deterministic policy that scored best
on held-out validation episodes, checked every few iterations and before the first: the exported
one) and, when ``eval_trials > 0``, ``evaluation.json``: the exported policy scored on seeded
episodes through the same evaluator as ``python -m grt.evaluate``. The run folder's ``policy.pt`` (no
optimizer state) is the trained policy; ``train.export=PATH`` copies it to PATH too, an explicit opt-in:
a shipped policy (a file under ``grt/policies/checkpoints``, what ``conf/policy/<name>.yaml`` points at)
is replaced only with ``train.overwrite_shipped=true`` as well, checked before any training.

A resume (``resume=DIR``) trains with the training's own config (:func:`grt.cli.train.resumed_config`). The
settings are read from a :class:`grt.rl.spec.PolicyTrainingSpec`, which the app makes of its config.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from grt.errors import OutputError, check_output_file
from grt.evaluators.collision import make_collision
from grt.evaluators.pool import build_session
from grt.evaluators.sim import SimEvaluator
from grt.geometry.mesh import load_mesh
from grt.policies.base import POLICY_KINDS
from grt.policies.rsl_rl import RslRlPolicy
from grt.redteam import episode_seeds
from grt.rl.spec import PolicyTrainingSpec
from grt.rl.train import (
    TrainSpec,
    ValidationSpec,
    export_policy,
    finished,
    plot_curve,
    train,
    write_json,
)
from grt.rl.vec_env import Shape, TaskVecEnv
from grt.targets import build
from grt.tasks import TaskInputError, check_fit, preflight, session_class, task_object

log = logging.getLogger("grt.train")


def train_policy(spec: PolicyTrainingSpec, out_dir: Path) -> dict:
    """Train (or resume, in ``out_dir``) the policy of ``spec``; returns ``train.json``'s figures
    (``iterations``, ``steps``, ``best_success``, ``wall_s``, ``selected``, ``evaluation``, ...).

    Raises:
        OutputError: ``train.export`` names a shipped policy without ``train.overwrite_shipped=true``, or a
            file that cannot be written (before any training).
    """
    task, train_cfg = spec.task, spec.train
    check_export(train_cfg)
    check_trainable(task)
    check_fit(task)  # no Vulkan: before the object and the workers
    done = finished(out_dir, int(train_cfg["iterations"])) if spec.resume else None
    if done is not None:  # a finished training: said, and not a file of it changes
        return {**done, "nothing_to_train": f"nothing to train: {out_dir} already trained {done['iterations']} "
                f"iterations (train.iterations={train_cfg['iterations']}); its files are as they were (a larger "
                "train.iterations trains longer)"}
    # built before the simulator starts: a class that cannot be built is one line, nothing written
    bc = train_cfg.get("bc")
    expert = build(bc["expert"], "train.bc.expert") if bc else None
    logger = build(spec.logger, "logger")
    mesh = load_mesh(task_object(task, spec.object, spec.cache_dir), settings=spec.mesh)
    if expert is not None:  # an expert of another task (train=insertion_state on task=push_cube): one line
        try:
            preflight(task, expert, mesh)
        except TaskInputError as err:
            raise TaskInputError(f"train.bc.expert (the warm start's expert of train={spec.name}): {err}; "
                                 "give a train config made for this task, or train.bc=null to start without "
                                 "a warm start") from None
    collision = make_collision("fast", mesh, None, f"{spec.cache_dir}/coacd", 64)  # as the evaluator
    parts = collision.parts(mesh)
    env = TaskVecEnv(task, [Shape.of(mesh, parts, spec.object)], num_envs=train_cfg["num_envs"],
                     workers=train_cfg["workers"], seed=train_cfg["seed"], max_steps=train_cfg["max_steps"],
                     success_bonus=float(train_cfg.get("success_bonus") or 0.0))
    logger.start(out_dir, name=f"train-{spec.name}", config=spec.config)
    val = train_cfg.get("validation") or {}
    score, session = (None, None) if not val else _validator(task, mesh, parts, int(val["trials"]))
    training = TrainSpec.from_config(
        train_cfg, out_dir, task_name=task["name"], task_cfg=task, init_checkpoint=spec.init_checkpoint,
        extra={"policy_name": spec.name, "object": spec.object},
        on_iteration=lambda row: logger.log_iteration(row["iteration"], row),
        expert=expert,
        bc={k: v for k, v in (bc or {}).items() if k != "expert"},
        validation=None if score is None else ValidationSpec(
            score, interval=int(val.get("interval", 10)), patience=int(val.get("patience", 5)), tie=val.get("tie"),
            perfect=1.0 if str(task.get("score", "success")) == "success" else None))
    try:
        result = train(env, training)
    finally:
        env.close()
        if session is not None:
            session.close()
    _export(spec, mesh, out_dir, result)
    write_json(out_dir / "train.json", result)
    logger.log_summary({k: v for k, v in result.items() if not isinstance(v, dict)})
    logger.finish()
    return result


def check_trainable(task: dict) -> None:
    """Refuse a task whose episodes do not step a closed-loop policy (the grasp task runs one planned grasp):
    PPO has no actions to learn there.

    Raises:
        TaskInputError: names the task, what it runs and the tasks PPO trains on.
    """
    cls = session_class(task)
    if "closed_loop" in cls.policy_kinds:
        return
    runs = " or ".join(POLICY_KINDS[k] for k in cls.policy_kinds) or "no closed-loop policy"
    raise TaskInputError(f"task={task.get('name')} ({cls.__name__}) runs {runs}: python -m grt.train trains a "
                         "closed-loop PPO policy, for a task whose episodes it steps (task=insertion, task=drawer, "
                         "a ManiSkill task such as task=push_cube)")


def _export(spec: PolicyTrainingSpec, mesh, out_dir: Path, result: dict) -> None:
    """Plot the curve, export the selected checkpoint as ``policy.pt`` (and to ``train.export``), evaluate
    it; adds ``selected``, ``evaluation`` and ``exported`` to ``result``."""
    plot_curve(out_dir / "metrics.csv", out_dir / "curve.png", title=f"{spec.name} on {spec.object}")
    best = next(out_dir / f for f in ("val_best.pt", "best.pt", "last.pt") if (out_dir / f).exists())
    result["selected"] = best.name
    policy_file = export_policy(best, out_dir / "policy.pt", metrics=result)
    if spec.eval_trials:
        result["evaluation"] = _evaluate(spec, policy_file, mesh, out_dir)
        export_policy(best, policy_file, metrics=result)
    if spec.train.get("export"):
        dest = export_policy(policy_file, Path(spec.train["export"]), metrics=result)
        result["exported"] = str(dest)


SHIPPED = Path(__file__).resolve().parents[1] / "policies" / "checkpoints"  # grt/policies/checkpoints


def check_export(train_cfg: dict) -> Path | None:
    """``train.export`` as a path (``None``: no export), refused before any training when it would replace
    a shipped policy without ``train.overwrite_shipped=true`` or cannot be written.

    Raises:
        OutputError: names the file and the flag that allows it.
    """
    export = train_cfg.get("export")
    if not export:
        return None
    dest = check_output_file(export, (".pt",), flag="train.export")
    shipped = dest.resolve().is_relative_to(SHIPPED)
    if shipped and dest.exists() and not train_cfg.get("overwrite_shipped", False):
        raise OutputError(f"train.export={export} would replace a policy shipped with GRT ({dest.name} in "
                          f"{SHIPPED}); add train.overwrite_shipped=true to replace it, or export elsewhere "
                          "(train.export=PATH; the run folder's policy.pt is always written)")
    return dest


def _validator(task: dict, mesh, parts, trials: int):
    """``checkpoint -> mean score`` of the deterministic policy on ``trials`` validation episodes (seeds
    disjoint from the evaluation's), in one session of this process; and the session."""
    session = build_session(task, None)
    session.load_object(mesh, parts)
    seeds = [10_000 + i for i in range(trials)]

    def validate(path: Path) -> float:
        session.policy = RslRlPolicy(str(path), task=task["name"])
        score = float(np.mean([session.run_trial(s).score for s in seeds]))
        log.info("validation of %s: %.4g", path.name, score)
        return score

    return validate, session


def _evaluate(spec: PolicyTrainingSpec, policy_file: Path, mesh, out_dir: Path) -> dict:
    """Score the trained policy on ``eval_trials`` seeded episodes (the red-team run's seeds for seed 42)."""
    policy = {"_target_": "grt.policies.rsl_rl.RslRlPolicy", "checkpoint": str(policy_file),
              "task": spec.task["name"]}
    seeds = episode_seeds(42, spec.eval_trials)
    start = time.perf_counter()
    # train.workers=0 steps the training envs in this process; the evaluation needs a worker process
    with SimEvaluator(task=spec.task, policy=policy, workers=max(1, int(spec.train["workers"])), nominal=mesh,
                      cache_dir=f"{spec.cache_dir}/coacd") as ev:
        res = ev.evaluate([mesh], seeds)[0]
    summary = {**res.summary(), "wall_s": time.perf_counter() - start}
    write_json(out_dir / "evaluation.json", {**summary, "seeds": seeds,
                                            "trials": [t.__dict__ for t in res.trials]})
    log.info("evaluation over %d trials: score %.4g, success %.3f %s", len(seeds), summary["score"],
             summary["success_rate"], summary["outcomes"])
    return summary
