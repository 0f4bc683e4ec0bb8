"""Benchmark of a served policy: ``python -m grt.bench remote [--trials N] [--workers W] [--calls C]``.

Serves the shipped insertion policy (``python -m grt.serve policy=POLICY serve.port=0``, a separate
process on this machine) and measures, in one run:

* per-call latency of ``act`` (one observation, as a trial sends it) through ``policy=remote`` over
  loopback, against the same call in process (median and 95th percentile, milliseconds);
* the evaluation's trials per second on the nominal plug through :class:`grt.evaluators.sim.SimEvaluator`
  with ``W`` workers (each worker opens its own connection), in process and remote, on the same seeds,
  and their ratio; with ``W`` > 1 also with one worker, remote, to show what the shared server costs;
* whether both gave the same outcomes (they must).

The last line printed is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import numpy as np

from grt.bench.grasp import compose


def _latency(policy, obs: dict, calls: int) -> tuple[float, float]:
    """Median and 95th percentile (ms) of ``policy.act(obs)``."""
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        policy.act(obs)
        times.append(time.perf_counter() - t)
    return float(np.median(times) * 1e3), float(np.percentile(times, 95) * 1e3)


def _trials_per_s(task: dict, policy: dict, mesh, seeds: list[int], workers: int, cache: str):
    from grt.evaluators.sim import SimEvaluator

    with SimEvaluator(task=task, policy=policy, workers=workers, nominal=mesh, progress=False, cache_dir=cache) as ev:
        ev.evaluate([mesh], seeds[:workers])  # start the workers (not timed)
        start = time.perf_counter()
        result = ev.evaluate([mesh], seeds)[0]
        return len(seeds) / (time.perf_counter() - start), result


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(prog="python -m grt.bench remote", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=32, help="trials per measurement (default 32)")
    ap.add_argument("--workers", type=int, default=2, help="evaluator worker processes (default 2)")
    ap.add_argument("--calls", type=int, default=2000, help="act calls of the latency measurement (default 2000)")
    ap.add_argument("--policy", default="insertion_state", help="policy config served (default insertion_state)")
    args = ap.parse_args(argv)

    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from grt.geometry.mesh import load_mesh
    from grt.policies.remote import connect
    from grt.redteam import episode_seeds

    cfg = compose(["task=insertion", f"policy={args.policy}"])
    task, local_cfg = (OmegaConf.to_container(cfg[k], resolve=True) for k in ("task", "policy"))
    mesh, seeds, cache = load_mesh(cfg.object), episode_seeds(42, args.trials), f"{cfg.paths.cache_dir}/coacd"
    server = subprocess.Popen([sys.executable, "-m", "grt.serve", "task=insertion", f"policy={args.policy}",
                               "serve.port=0"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        url = server.stdout.readline().strip()
        remote, local = connect(url), instantiate(cfg.policy)
        obs = {k: np.zeros((1, *v), np.float32) for k, v in remote.obs_spec.items()}
        remote.reset(0)
        local_ms = _latency(local, obs, args.calls)
        remote_ms = _latency(remote, obs, args.calls)
        remote.close()
        remote_cfg = {"_target_": "grt.policies.remote.connect", "url": url}
        local_rate, local_result = _trials_per_s(task, local_cfg, mesh, seeds, args.workers, cache)
        remote_rate, remote_result = _trials_per_s(task, remote_cfg, mesh, seeds, args.workers, cache)
        one_rate = _trials_per_s(task, remote_cfg, mesh, seeds, 1, cache)[0] if args.workers > 1 else remote_rate
    finally:
        server.kill()
        server.wait()
    same = [(t.seed, t.mode, t.score) for t in local_result.trials] == \
        [(t.seed, t.mode, t.score) for t in remote_result.trials]
    figures = {"policy": args.policy, "url": url, "trials": args.trials, "workers": args.workers,
               "inprocess_act_ms_median": round(local_ms[0], 4), "inprocess_act_ms_p95": round(local_ms[1], 4),
               "remote_act_ms_median": round(remote_ms[0], 4), "remote_act_ms_p95": round(remote_ms[1], 4),
               "inprocess_trials_per_s": round(local_rate, 3), "remote_trials_per_s": round(remote_rate, 3),
               "remote_vs_inprocess": round(remote_rate / local_rate, 3),
               "remote_1_worker_trials_per_s": round(one_rate, 3),
               "mean_steps_per_trial": round(float(np.mean([t.info.get("steps", 0) for t in remote_result.trials])), 1),
               "same_outcomes": same, "success_rate": remote_result.success_rate}
    print(f"act latency     in process {local_ms[0]:.3f} ms (p95 {local_ms[1]:.3f}), remote over loopback "
          f"{remote_ms[0]:.3f} ms (p95 {remote_ms[1]:.3f})")
    print(f"evaluation      {args.workers} workers: in process {local_rate:.2f} trials/s, remote {remote_rate:.2f} "
          f"trials/s = {remote_rate / local_rate:.2f}x; remote with 1 worker {one_rate:.2f} trials/s")
    print(f"outcomes        {'identical' if same else 'DIFFERENT'} ({args.trials} trials, success rate "
          f"{remote_result.success_rate:.3f})")
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
