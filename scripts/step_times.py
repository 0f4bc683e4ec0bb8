"""Measure one task's step times in one process (the figures behind each task session's ``STEP_S``, ``RESET_S``
and the grasp task's ``CAPTURE_S`` / ``PLAN_S``, which give the worker pool's default ``trial_timeout``):
``PYTHONPATH=$PWD python scripts/step_times.py TRIALS task=insertion policy=insertion_state``.

Builds the composed ``run`` config's task session with its policy in this process, loads the nominal object
(CoACD parts), runs ``TRIALS`` seeded trials and prints the slowest trial's time per control step (its whole
wall time, reset and capture included, over its steps) and, per phase, the count, mean, 99th percentile and
maximum wall time in ms: a closed-loop task's control step (the policy's ``act`` and the simulation step
together) and its reset (the scene rebuilt); the grasp task's control step, its cameras' capture and the
planner's ``plan``. Run it on a loaded machine: the defaults are the worst case seen, times a margin.
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from pathlib import Path

import hydra
import numpy as np
from hydra import compose, initialize_config_dir

from grt.config import plain
from grt.evaluators.collision import make_collision
from grt.geometry.mesh import load_mesh
from grt.redteam import episode_seeds

CONF = Path(__file__).resolve().parents[1] / "conf"


def timed(times: dict, key: str, fn):
    """``fn`` whose every call's wall time (s) is added to ``times[key]``."""

    def wrapper(*args, **kwargs):
        start = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            times[key].append(time.perf_counter() - start)

    return wrapper


def main(trials: int, overrides: list[str]) -> None:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="run", overrides=overrides)
    task, policy = plain(cfg.task), plain(cfg.policy)
    session = hydra.utils.instantiate(task["session"], policy=hydra.utils.instantiate(policy), _convert_="all")
    mesh = load_mesh(cfg.object)
    parts = make_collision("coacd", cache_dir=str(Path(cfg.paths.cache_dir) / "coacd")).parts(mesh)
    session.load_object(mesh, parts)
    times: dict[str, list[float]] = defaultdict(list)
    if hasattr(session, "_step_batch"):  # a closed-loop task: the policy acts, then the simulation steps
        session.policy.act = timed(times, "act", session.policy.act)
        session._step_batch = timed(times, "sim", session._step_batch)
        session._reset_batch = timed(times, "reset", session._reset_batch)
    else:  # the grasp task
        env = session.unwrapped
        session.env.step = timed(times, "control step", session.env.step)
        env.capture_object_cloud = timed(times, "capture", env.capture_object_cloud)
        session.policy.plan = timed(times, "plan", session.policy.plan)
        session.env.reset = timed(times, "reset", session.env.reset)
    modes, start, per_trial = defaultdict(int), time.perf_counter(), []
    for seed in episode_seeds(cfg.budget.seed, trials):
        begin, before = time.perf_counter(), {k: len(v) for k, v in times.items()}
        modes[session.run_trial(seed).mode] += 1
        steps = len(times["sim" if "sim" in times else "control step"]) - before.get("sim", before.get("control step", 0))
        per_trial.append((time.perf_counter() - begin, steps))
    wall = time.perf_counter() - start
    if "act" in times:  # one control step: the policy's act and the simulation step after it
        times["control step"] = [a + s for a, s in zip(times["act"], times["sim"], strict=False)]
    print(f"{' '.join(overrides)}: {trials} trials in {wall:.1f} s, outcomes {dict(modes)}")
    slowest = max(per_trial, key=lambda t: t[0] / max(t[1], 1))
    longest = max(per_trial)
    print(f"  slowest trial per step: {1000 * slowest[0] / max(slowest[1], 1):.2f} ms ({slowest[1]} control steps in "
          f"{slowest[0]:.2f} s, everything included); longest trial {longest[0]:.2f} s ({longest[1]} steps)")
    for key, values in sorted(times.items()):
        ms = 1000 * np.asarray(values)
        print(f"  {key:<13} n={len(ms):<6} mean {ms.mean():8.2f} ms  p99 {np.percentile(ms, 99):8.2f} ms  "
              f"max {ms.max():8.2f} ms")
    session.close()


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2:])
