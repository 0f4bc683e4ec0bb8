"""Benchmark of the insertion evaluation: ``python -m grt.bench insertion [--trials N] [--workers W]``.

Measures, in one run, on the nominal plug with a policy (default: the shipped state policy):

* raw simulation speed: ``env.step`` calls per second of GRT-Insert-v1 in this process, with the
  arm servoing to the target (one control step = 5 physics steps at 100 Hz);
* trials per second in this process (one session, no worker pool): the baseline;
* trials per second through :class:`grt.evaluators.sim.SimEvaluator` with ``W`` worker processes,
  after start-up, and its speed-up over the in-process baseline measured in the same run.

The last line printed is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from grt.bench.grasp import compose


def main(argv: list[str] | None = None) -> None:
    from grt.policies.servo import ServoInsertionPolicy

    episode_bench(argv, "insertion", "insertion_state", "usb_plug", ServoInsertionPolicy, __doc__)


def episode_bench(argv: list[str] | None, task_name: str, default_policy: str, default_object: str,
                  scripted, doc: str | None) -> dict:
    """The benchmark of a closed-loop task (``EpisodeSession``): simulation speed with the analytic
    policy ``scripted()``, trials/s in process (baseline) and through the worker pool; prints the
    figures and, last, one JSON line; returns the figures."""
    ap = argparse.ArgumentParser(prog=f"python -m grt.bench {task_name}", description=doc,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=32, help="trials per measurement (default 32)")
    ap.add_argument("--workers", type=int, default=2, help="evaluator worker processes (default 2)")
    ap.add_argument("--policy", default=default_policy, help=f"policy config name (default {default_policy})")
    ap.add_argument("--object", default=default_object, help=f"object (default {default_object})")
    args = ap.parse_args(argv)

    from omegaconf import OmegaConf

    from grt.evaluators.collision import make_collision
    from grt.evaluators.pool import build_session
    from grt.evaluators.sim import SimEvaluator
    from grt.geometry.mesh import load_mesh
    from grt.redteam import episode_seeds

    cfg = compose([f"task={task_name}", f"policy={args.policy}", f"object={args.object}"])
    task, policy_cfg = (OmegaConf.to_container(cfg[k], resolve=True) for k in ("task", "policy"))
    mesh = load_mesh(cfg.object)
    # the parts the evaluator simulates the nominal object with (its "fast" collision), for both measurements
    parts = make_collision("fast", mesh, None, f"{cfg.paths.cache_dir}/coacd", 64).parts(mesh)
    seeds = episode_seeds(42, args.trials)

    session = build_session(task, policy_cfg)
    session.load_object(mesh, parts)
    expert, steps = scripted(), 0
    start = time.perf_counter()
    for seed in seeds[:8]:
        obs = session.reset(seed)
        for _ in range(40):
            obs, *_ = session.step(expert.act({k: v[None] for k, v in obs.items()})[0])
            steps += 1
    sim_rate = steps / (time.perf_counter() - start)
    start = time.perf_counter()
    local = [session.run_trial(s) for s in seeds]
    local_s = time.perf_counter() - start
    session.close()

    with SimEvaluator(task=task, policy=policy_cfg, workers=args.workers, nominal=mesh, progress=False,
                      cache_dir=f"{cfg.paths.cache_dir}/coacd") as ev:
        t0 = time.perf_counter()
        ev.evaluate([mesh], seeds[:args.workers])  # start the workers (not timed below)
        startup_s = time.perf_counter() - t0
        start = time.perf_counter()
        result = ev.evaluate([mesh], seeds)[0]
        pool_s = time.perf_counter() - start
    figures = {
        "task": task_name, "policy": args.policy, "object": str(cfg.object), "trials": args.trials,
        "workers": args.workers, "sim_steps_per_s": round(sim_rate, 1),
        "inprocess_trials_per_s": round(args.trials / local_s, 3),
        "pool_trials_per_s": round(args.trials / pool_s, 3),
        "speedup_vs_inprocess": round(local_s / pool_s, 2),
        "mean_steps_per_trial": round(float(np.mean([t.info.get("steps", 0) for t in result.trials])), 1),
        "score": result.score, "success_rate": result.success_rate,
        "inprocess_success_rate": float(np.mean([t.success for t in local])),
        "worker_startup_s": round(startup_s, 2),
    }
    print(f"simulation      {figures['sim_steps_per_s']:.0f} control steps/s (this process)")
    print(f"in process      {figures['inprocess_trials_per_s']:.2f} trials/s (baseline)")
    print(f"{args.workers} workers       {figures['pool_trials_per_s']:.2f} trials/s = "
          f"{figures['speedup_vs_inprocess']:.2f}x the baseline (after {startup_s:.1f} s start-up)")
    print(f"score           {result.score:.4g} {cfg.task.get('score_unit') or ''}, success {result.success_rate:.3f} "
          f"({figures['mean_steps_per_trial']:.0f} steps per trial)")
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
