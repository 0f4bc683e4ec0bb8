"""Train a task's policy with PPO (rsl-rl's OnPolicyRunner); a Hydra app.

    python scripts/train_policy.py task=insertion train=insertion_state
    python scripts/train_policy.py task=insertion train=insertion_pcd
    python scripts/train_policy.py resume=outputs/train/insertion/insertion_state/<time>

The run folder gets ``metrics.csv`` (one row per PPO iteration), ``last.pt`` / ``best.pt`` (rsl-rl
checkpoints with the GRT config inside, resumable), ``curve.png`` (training curve), ``train.json``
(figures), with ``train.validation`` also ``val_best.pt`` (the deterministic policy that scored best
on held-out validation episodes, checked every few iterations and before the first: the exported
one) and, when ``eval_trials > 0``, ``evaluation.json``: the exported policy scored on seeded
episodes through the same evaluator as ``python -m grt.evaluate``. The exported policy file
(``train.export``, no optimizer state) is what ``conf/policy/<name>.yaml`` points at.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

import grt.config  # noqa: F401 - registers schemas and resolvers
import grt.runfolder  # noqa: F401 - registers resume_or (hydra.run.dir)

log = logging.getLogger("train_policy")


def _plain(node) -> dict:
    return OmegaConf.to_container(node, resolve=True)


def run(cfg: DictConfig, out_dir: Path) -> dict:
    from grt.evaluators.collision import make_collision
    from grt.geometry.mesh import load_mesh
    from grt.rl.train import export_policy, plot_curve, train, write_json
    from grt.rl.vec_env import Shape, TaskVecEnv

    mesh = load_mesh(cfg.object)
    collision = make_collision("fast", mesh, None, f"{cfg.paths.cache_dir}/coacd", 64)  # as the evaluator
    parts = collision.parts(mesh)
    task, train_cfg = _plain(cfg.task), _plain(cfg.train)
    env = TaskVecEnv(task, [Shape.of(mesh, parts, str(cfg.object))], num_envs=train_cfg["num_envs"],
                     workers=train_cfg["workers"], seed=train_cfg["seed"], max_steps=train_cfg["max_steps"])
    bc = train_cfg.get("bc")
    expert = instantiate(cfg.train.bc.expert) if bc else None
    logger = instantiate(cfg.logger)
    logger.start(out_dir, name=f"train-{train_cfg['name']}", config=_plain(cfg))
    val = train_cfg.get("validation") or {}
    validate, session = (None, None) if not val else _validator(task, mesh, parts, int(val["trials"]))
    try:
        result = train(env, train_cfg, out_dir, task_name=cfg.task.name, task_cfg=task,
                       iterations=train_cfg["iterations"], init_checkpoint=cfg.init_checkpoint,
                       save_interval=train_cfg["save_interval"], target_success=train_cfg["target_success"],
                       patience=train_cfg["patience"], extra={"policy_name": train_cfg["name"],
                                                              "object": str(cfg.object)},
                       on_iteration=lambda row: logger.log_iteration(row["iteration"], row), expert=expert,
                       bc={k: v for k, v in (bc or {}).items() if k != "expert"}, validate=validate,
                       val_interval=int(val.get("interval", 10)), val_patience=int(val.get("patience", 5)),
                       val_tie=val.get("tie"),
                       val_perfect=1.0 if str(cfg.task.get("score", "success")) == "success" else None)
    finally:
        env.close()
        if session is not None:
            session.close()
    plot_curve(out_dir / "metrics.csv", out_dir / "curve.png", title=f"{train_cfg['name']} on {cfg.object}")
    best = next(out_dir / f for f in ("val_best.pt", "best.pt", "last.pt") if (out_dir / f).exists())
    result["selected"] = best.name
    policy_file = export_policy(best, out_dir / "policy.pt", metrics=result)
    if cfg.eval_trials:
        result["evaluation"] = _evaluate(cfg, policy_file, mesh, out_dir)
        export_policy(best, policy_file, metrics=result)
    if train_cfg.get("export"):
        dest = export_policy(policy_file, Path(train_cfg["export"]), metrics=result)
        result["exported"] = str(dest)
    write_json(out_dir / "train.json", result)
    logger.log_summary({k: v for k, v in result.items() if not isinstance(v, dict)})
    logger.finish()
    return result


def _validator(task: dict, mesh, parts, trials: int):
    """``checkpoint -> mean score`` of the deterministic policy on ``trials`` validation episodes (seeds
    disjoint from the evaluation's), in one session of this process; and the session."""
    import numpy as np

    from grt.evaluators.pool import build_session
    from grt.policies.rsl_rl import RslRlPolicy

    session = build_session(task, None)
    session.load_object(mesh, parts)
    seeds = [10_000 + i for i in range(trials)]

    def validate(path: Path) -> float:
        session.policy = RslRlPolicy(str(path), task=task["name"])
        score = float(np.mean([session.run_trial(s).score for s in seeds]))
        log.info("validation of %s: %.4g", path.name, score)
        return score

    return validate, session


def _evaluate(cfg: DictConfig, policy_file: Path, mesh, out_dir: Path) -> dict:
    """Score the trained policy on ``eval_trials`` seeded episodes (the red-team run's seeds for seed 42)."""
    from grt.evaluators.sim import SimEvaluator
    from grt.redteam import episode_seeds
    from grt.rl.train import write_json

    policy = {"_target_": "grt.policies.rsl_rl.RslRlPolicy", "checkpoint": str(policy_file), "task": cfg.task.name}
    seeds = episode_seeds(42, int(cfg.eval_trials))
    start = time.perf_counter()
    with SimEvaluator(task=_plain(cfg.task), policy=policy, workers=cfg.train.workers, nominal=mesh,
                      cache_dir=f"{cfg.paths.cache_dir}/coacd") as ev:
        res = ev.evaluate([mesh], seeds)[0]
    summary = {**res.summary(), "wall_s": time.perf_counter() - start}
    write_json(out_dir / "evaluation.json", {**summary, "seeds": seeds,
                                            "trials": [t.__dict__ for t in res.trials]})
    log.info("evaluation over %d trials: score %.4g, success %.3f %s", len(seeds), summary["score"],
             summary["success_rate"], summary["outcomes"])
    return summary


@hydra.main(config_path="../conf", config_name="train_policy", version_base="1.3")
def main(cfg: DictConfig) -> float:
    from grt.cli._common import exit_on_user_error

    out_dir = Path(HydraConfig.get().runtime.output_dir)
    with exit_on_user_error():
        result = run(cfg, out_dir)
    print(f"trained {result['iterations']} iterations ({result['steps']} steps) in {result['wall_s']:.0f} s; "
          f"best training success {result['best_success']:.2f}; files in {out_dir}")
    ev = result.get("evaluation")
    if ev:
        print(f"evaluation: {cfg.task.score} {ev['score']:.4g} (success {ev['success_rate']:.3f}) over "
              f"{ev['trials']} trials {ev['outcomes']}")
    return float(result["best_success"])


if __name__ == "__main__":
    main()
