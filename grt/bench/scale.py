"""Scaling benchmark of ``evaluator=ray``: ``python -m grt.bench scale [--workers W] [--trials N] [--repeats R]``.

Measures, in one run, on the insertion task (the nominal plug, policy ``insertion_state`` by default,
the real simulator):

* trials per second of the local worker pool (``evaluator=sim``) and of Ray actors (``evaluator=ray``,
  a Ray started here, or the cluster at ``--address``), each with ``W`` workers started and warmed up
  before timing, on the same seeds and the same candidate; each measurement is one ``evaluate`` call
  of ``N`` trials of one candidate, alternated pool/Ray ``R`` times
  (pool first, then Ray first, ...) so the machine's load hits both; the ratio ray/pool;
* a population (``--population`` candidates x ``--population-trials`` trials) in one ``evaluate`` call,
  as the red-team loop scores it, against one call per candidate, per backend;
* start-up: the pool's (``W`` processes build their simulators) vs Ray's (connect, or start a local
  Ray, then ``W`` actors build theirs);
* overheads, each for both backends: the driver's CPU seconds per trial (``time.process_time`` of this
  process over an evaluation, Ray's threads in it included); the idle seconds per call (wall time
  minus the workers' mean busy seconds: dispatch, results, the wait for the slower chunk); the workers'
  seconds outside trials per job (the candidate's load; for Ray also each trial's call); and Ray's round
  trip of an actor call that does nothing (``SimActor.pid``, ``--calls`` calls one after another);
* a PROJECTION (computed, not measured) of the paper protocol's wall time per object-policy pair on
  1-32 nodes of ``--cores-per-node`` cores, from these figures (insertion) and from the per-trial rates
  docs/benchmarks.md records for the other tasks; see :func:`project` for the model and its assumptions.

Progress lines while it runs; the last line printed is one JSON object with every figure.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from grt.bench.grasp import CONF_DIR, compose

NODES = (1, 2, 4, 8, 16, 32)
#: Pool rates with 2 workers on this 2-core machine, from docs/benchmarks.md (the insertion row is
#: replaced by this run's measurement): name, task config, trials/s, the longest trial over the mean one
#: (a failing trial runs to the episode's limit), and where the numbers come from.
DOCUMENTED = (
    ("grasp antipodal", "grasp", 5.0, 1.5,
     "~5 trials/s (issue 28); a trial 0.36-0.60 s in one process, so the longest ~1.5x the mean"),
    ("grasp contact_graspnet", "grasp", 0.56, 7.1,
     "0.56 trials/s (measured while another evaluation shared the cores); no grasp found = 10 inferences "
     "of 2.41 s: (3.57 + 9 x 2.41) / 3.57 s"),
    ("insertion insertion_state", "insertion", 14.8, None,
     "measured by this run (docs: 14.8 trials/s); the longest trial: the mean one + the steps to the "
     "episode's limit (256) at the measured seconds per control step"),
    ("drawer drawer_state", "drawer", 4.64, 2.5,
     "4.64 trials/s; a nominal trial ~200 control steps, a failing one runs to 500"),
)


def _loadavg() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else []


def _say(line: str) -> None:
    print(line, flush=True)


def measure_call(ev, mesh, seeds: list[int]) -> dict:
    """One timed ``evaluate`` call of ``mesh`` on ``seeds``: wall and driver CPU seconds, the workers'
    busy seconds (loading + trials) and trial seconds, the control steps, and the outcomes."""
    cpu, start = time.process_time(), time.perf_counter()
    result = ev.evaluate([mesh], seeds)[0]
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    trial_s = [float(t.info.get("wall_s", 0.0)) for t in result.trials]
    return {"wall_s": wall, "driver_cpu_s": cpu, "busy_s": float(result.wall_s), "trial_s": float(sum(trial_s)),
            "trial_s_max": max(trial_s), "steps": int(sum(t.info.get("steps", 0) for t in result.trials)),
            "per_trial": [(int(t.info.get("steps", 0)), float(t.info.get("wall_s", 0.0))) for t in result.trials],
            "jobs": math.ceil(len(seeds) / math.ceil(len(seeds) / ev.workers)), "trials": len(seeds),
            "outcomes": [(t.seed, t.mode, t.score) for t in result.trials]}


def summarize(calls: list[dict], workers: int) -> dict:
    """Rates and overheads of one backend over its timed calls."""
    trials = sum(c["trials"] for c in calls)
    wall = sum(c["wall_s"] for c in calls)
    busy = sum(c["busy_s"] for c in calls)
    in_trials = sum(c["trial_s"] for c in calls)
    return {
        "trials_per_s": trials / wall,
        "trials_per_s_each": [c["trials"] / c["wall_s"] for c in calls],
        "driver_cpu_ms_per_trial": 1e3 * sum(c["driver_cpu_s"] for c in calls) / trials,
        "idle_s_per_call": (wall - busy / workers) / len(calls),
        "non_trial_s_per_job": (busy - in_trials) / sum(c["jobs"] for c in calls),
        "trial_s_mean": in_trials / trials,
        "trial_s_max": max(c["trial_s_max"] for c in calls),
        "steps_per_trial": sum(c["steps"] for c in calls) / trials,
        "worker_s_per_trial": workers * wall / trials,
    }


def step_seconds(calls: list[dict], fallback: float) -> tuple[float, str]:
    """Seconds per control step: the slope of a trial's seconds over its steps (least squares over every
    trial timed), or ``fallback`` where the trials' step counts hardly differ; and which one it is."""
    steps, seconds = np.array([p for c in calls for p in c["per_trial"]], float).T
    if np.ptp(steps) >= 5:
        slope = float(np.polyfit(steps, seconds, 1)[0])
        if slope > 0:
            return slope, f"fit over {len(steps)} trials of {int(steps.min())}-{int(steps.max())} steps"
    return fallback, "docs/benchmarks.md (179 control steps/s in one process)"


def measure_population(pool, ray_ev, mesh, args: argparse.Namespace) -> dict:
    """A population of ``--population`` candidates x ``--population-trials`` trials, scored as the red-team
    loop scores it (one ``evaluate`` call of every candidate) and as it did before 2026-11-25 (one call
    per candidate), alternated per backend, ``--repeats`` times; trials/s of each and their ratio.

    The candidates are copies of one mesh (their outcomes must then be equal, call by call): what is
    timed is the dispatch, the wait for each call's slowest chunk, and the loads.
    """
    from grt.redteam import episode_seeds

    seeds = episode_seeds(11, args.population_trials)
    meshes = [mesh.copy() for _ in range(args.population)]
    trials = args.population * args.population_trials
    out: dict = {"candidates": args.population, "trials_per_candidate": args.population_trials}
    for name, ev in (("pool", pool), ("ray", ray_ev)):
        wall = {"one_call": 0.0, "call_per_candidate": 0.0}
        outcomes = []
        for r in range(args.repeats):
            for mode in (("one_call", "call_per_candidate") if r % 2 == 0 else ("call_per_candidate", "one_call")):
                start = time.perf_counter()
                results = (ev.evaluate(meshes, seeds) if mode == "one_call"
                           else [ev.evaluate([m], seeds)[0] for m in meshes])
                wall[mode] += time.perf_counter() - start
                outcomes.append([[(t.seed, t.mode, t.score) for t in res.trials] for res in results])
        rates = {mode: round(args.repeats * trials / w, 3) for mode, w in wall.items()}
        out[name] = {"trials_per_s_one_call": rates["one_call"],
                     "trials_per_s_call_per_candidate": rates["call_per_candidate"],
                     "one_call_over_call_per_candidate": round(rates["one_call"] / rates["call_per_candidate"], 3),
                     "same_outcomes": all(o == outcomes[0] for o in outcomes)
                     and all(c == outcomes[0][0] for c in outcomes[0])}
        _say(f"population ({name}): {args.population} candidates x {args.population_trials} trials: one call "
             f"{rates['one_call']:.2f} trials/s, a call per candidate {rates['call_per_candidate']:.2f} trials/s")
    return out


def noop_round_trip_ms(ev, calls: int) -> tuple[float, float]:
    """Median and 95th percentile (ms) of a Ray actor call that does nothing much (``SimActor.pid``),
    made one after another on a ready actor of ``ev`` (a :class:`~grt.evaluators.ray_pool.RayEvaluator`)."""
    import ray

    handle = ev.pool.actors[0].handle
    ray.get(handle.pid.remote())
    times = []
    for _ in range(calls):
        t = time.perf_counter()
        ray.get(handle.pid.remote())
        times.append(time.perf_counter() - t)
    return float(np.median(times) * 1e3), float(np.percentile(times, 95) * 1e3)


def _protocol() -> dict:
    """Population, iterations and top-k of ``conf/budget/paper.yaml``; each task's paper trial count; the YAML's
    ``confirm_trials`` as written (``${.trials}``: a candidate's trials, resolved only within a task)."""
    from omegaconf import OmegaConf

    paper = OmegaConf.load(Path(CONF_DIR) / "budget" / "paper.yaml")
    trials = {name: int(OmegaConf.load(Path(CONF_DIR) / "task" / f"{name}.yaml").trials)
              for name in ("grasp", "insertion", "drawer")}
    return {"population": int(paper.population), "iterations": int(paper.iterations), "top_k": int(paper.top_k),
            "confirm_trials_in_paper_yaml": str(OmegaConf.to_container(paper).get("confirm_trials", 0)),
            "trials": trials}


def call_seconds(trials: int, candidates: int, workers: int, cost: dict) -> tuple[float, float]:
    """Low and high wall seconds of one ``evaluate`` call of ``candidates`` x ``trials`` on ``workers``.

    The evaluator cuts each candidate's trials into chunks of ``ceil(trials / workers)`` (one job each);
    the jobs run in rounds over the workers. Low: every trial takes the mean time. High: the slowest
    chunk holds one trial at the episode's limit (``long_s``). Both add the idle seconds per call and a
    load per job, and neither is below what one driver can dispatch (``driver_s`` per trial).
    """
    size = math.ceil(trials / workers)
    jobs = candidates * math.ceil(trials / size)
    rounds = math.ceil(jobs / workers)
    low = cost["idle_s"] + rounds * (cost["load_s"] + size * cost["trial_s"])
    high = low + max(cost["long_s"] - cost["trial_s"], 0.0)
    floor = cost["idle_s"] + candidates * trials * cost["driver_s"]
    return max(low, floor), max(high, floor)


def project(costs: dict[str, dict], protocol: dict, cores: int, confirm_trials: int, startup_s: float) -> dict:
    """Projected wall seconds of the paper protocol per object-policy pair, per task and node count.

    Model (every figure from this run, or from docs/benchmarks.md, per task in ``costs``): one worker
    per core, each as fast as a worker measured here; the protocol is the nominal evaluation, then
    ``iterations`` iterations of ``population`` candidates x the task's trials, then the nominal object
    and ``top_k`` CrashShapes confirmed on ``confirm_trials`` fresh episodes, plus one start-up. The
    iterations are sequential (each population needs the previous one's scores). ``population``: as GRT
    runs the search since 2026-11-25, a whole population per evaluate call (at most population x trials
    busy workers), the confirmation's shapes in one call too; ``per_candidate``: as it ran before, one
    candidate per call (at most ``trials`` busy workers).
    Not modelled: the network between nodes (Ray's calls are pipelined, two per actor), a driver whose
    poll grows with the calls in flight (its CPU per trial is measured with ``W`` actors only), the
    driver's deformation and optimizer steps (milliseconds per candidate), ``collision=coacd`` (seconds per
    candidate), implausible candidates (not simulated: they shorten a run).
    """
    pop, iters, top_k = protocol["population"], protocol["iterations"], protocol["top_k"]
    out = {}
    for name, cost in costs.items():
        trials = cost["trials"]
        rows = []
        for nodes in NODES:
            workers = nodes * cores
            one = call_seconds(trials, 1, workers, cost)
            pop_call = call_seconds(trials, pop, workers, cost)
            confirm = call_seconds(confirm_trials, 1, workers, cost) if confirm_trials else (0.0, 0.0)
            confirm_all = (call_seconds(confirm_trials, 1 + top_k, workers, cost) if confirm_trials
                           else (0.0, 0.0))
            single = [startup_s + (1 + pop * iters) * one[k] + (1 + top_k) * confirm[k] for k in (0, 1)]
            population = [startup_s + one[k] + iters * pop_call[k] + confirm_all[k] for k in (0, 1)]
            rows.append({"nodes": nodes, "workers": workers, "busy_population": min(workers, pop * trials),
                         "busy_per_candidate": min(workers, trials),
                         "population_s": [round(x, 1) for x in population],
                         "per_candidate_s": [round(x, 1) for x in single]})
        out[name] = {"trials": trials, "rows": rows}
    return out


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _span(pair: list[float]) -> str:
    low, high = _duration(pair[0]), _duration(pair[1])
    return low if low == high else f"{low}-{high}"


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m grt.bench scale", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=2, help="workers of each backend (default 2)")
    ap.add_argument("--trials", type=int, default=64, help="trials per timed evaluate call (default 64)")
    ap.add_argument("--repeats", type=int, default=4,
                    help="timed calls per backend, alternated: pool first, then Ray first, ... (default 4)")
    ap.add_argument("--address", default="local",
                    help="Ray: local (started here, default), auto, HOST:PORT or ray://HOST:PORT (a cluster)")
    ap.add_argument("--population", type=int, default=8,
                    help="candidates of the population measurement: one evaluate call vs one call each (default 8)")
    ap.add_argument("--population-trials", type=int, default=8,
                    help="trials per candidate of the population measurement (default 8, as budget=quick)")
    ap.add_argument("--calls", type=int, default=200, help="no-op actor calls timed (default 200)")
    ap.add_argument("--policy", default="insertion_state", help="insertion policy config (default insertion_state)")
    ap.add_argument("--cores-per-node", type=int, default=16, help="cores per node of the projection (default 16)")
    ap.add_argument("--confirm-trials", type=int, default=32,
                    help="fresh episodes of the projected confirmation (default 32, as experiment=table2_cgn; "
                         "conf/budget/paper.yaml sets none)")
    args = ap.parse_args(argv)
    for name in ("workers", "trials", "repeats", "calls", "cores_per_node", "population", "population_trials"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.confirm_trials < 0:
        ap.error(f"--confirm-trials must be >= 0, got {args.confirm_trials}")
    return args


def measure(args: argparse.Namespace) -> tuple[dict, dict[str, list[dict]], dict]:
    """Start both backends, time them alternately and Ray's no-op calls: the figures, each backend's
    timed calls, and the task config."""
    from omegaconf import OmegaConf

    from grt.evaluators.ray_pool import RayEvaluator
    from grt.evaluators.sim import SimEvaluator
    from grt.geometry.mesh import load_mesh
    from grt.redteam import episode_seeds

    load_before = _loadavg()
    cfg = compose(["task=insertion", f"policy={args.policy}"])
    task, policy = (OmegaConf.to_container(cfg[k], resolve=True) for k in ("task", "policy"))
    mesh, cache = load_mesh(cfg.object), f"{cfg.paths.cache_dir}/coacd"
    seeds, warm = episode_seeds(42, args.trials), episode_seeds(7, args.workers)
    common = {"task": task, "policy": policy, "workers": args.workers, "nominal": mesh, "progress": False,
              "cache_dir": cache}
    _say(f"scale: insertion, {args.policy}, nominal {cfg.object}; {args.workers} workers each, {args.trials} "
         f"trials x {args.repeats} calls per backend; load average {' '.join(map(str, load_before))}")
    figures: dict = {"task": "insertion", "policy": args.policy, "object": str(cfg.object), "workers": args.workers,
                     "trials": args.trials, "repeats": args.repeats, "address": args.address,
                     "loadavg_before": load_before}
    calls: dict[str, list[dict]] = {"pool": [], "ray": []}
    pool = ray_ev = None
    try:
        start = time.perf_counter()
        pool = SimEvaluator(**common)
        pool.start(say=None)
        figures["pool_startup_s"] = round(time.perf_counter() - start, 2)
        _say(f"pool: {pool.workers} workers ready in {figures['pool_startup_s']:.1f} s")
        start = time.perf_counter()
        ray_ev = RayEvaluator(address=args.address, **common)
        connect_s = time.perf_counter() - start
        ray_ev.start(say=None)
        startup_s = time.perf_counter() - start
        figures.update(ray_connect_s=round(connect_s, 2), ray_actors_ready_s=round(startup_s - connect_s, 2),
                       ray_startup_s=round(startup_s, 2), ray_actors=ray_ev.workers)
        _say(f"ray: {'started' if args.address == 'local' else 'joined'} at {args.address} in {connect_s:.1f} s, "
             f"{ray_ev.workers} actors ready {startup_s - connect_s:.1f} s later")
        for ev in (pool, ray_ev):  # each worker's first trial (shader and allocator warm-up): not timed
            ev.evaluate([mesh], warm)
        for r in range(args.repeats):
            order = ("pool", "ray") if r % 2 == 0 else ("ray", "pool")
            for name in order:
                calls[name].append(measure_call(pool if name == "pool" else ray_ev, mesh, seeds))
            _say(f"call {r + 1}/{args.repeats}: " + ", ".join(
                f"{n} {calls[n][-1]['trials'] / calls[n][-1]['wall_s']:.2f} trials/s" for n in order))
        figures["population"] = measure_population(pool, ray_ev, mesh, args)
        median, p95 = noop_round_trip_ms(ray_ev, args.calls)
        _say(f"ray: no-op actor call {median:.2f} ms median, {p95:.2f} ms p95 ({args.calls} calls)")
        figures.update(ray_noop_call_ms_median=round(median, 3), ray_noop_call_ms_p95=round(p95, 3),
                       ray_backend=ray_ev.backend_info())
    finally:
        for ev in (ray_ev, pool):
            if ev is not None:
                ev.close()
    return figures, calls, task


def compare(figures: dict, calls: dict[str, list[dict]], workers: int) -> dict[str, dict]:
    """Add the rates, their ratio and the overheads of both backends to ``figures``; returns the stats."""
    stats = {name: summarize(c, workers) for name, c in calls.items()}
    pool, ray = stats["pool"], stats["ray"]
    first = calls["pool"][0]["outcomes"]
    figures.update(
        pool_trials_per_s=round(pool["trials_per_s"], 3), ray_trials_per_s=round(ray["trials_per_s"], 3),
        ray_over_pool=round(ray["trials_per_s"] / pool["trials_per_s"], 3),
        ray_over_pool_each=[round(r["trials"] / r["wall_s"] / (p["trials"] / p["wall_s"]), 3)
                            for p, r in zip(calls["pool"], calls["ray"], strict=True)],
        same_outcomes=all(c["outcomes"] == first for c in calls["pool"] + calls["ray"]),
        success_rate=round(float(np.mean([mode == "success" for _, mode, _ in first])), 3))
    for name, s in stats.items():
        figures[f"{name}_trials_per_s_each"] = [round(x, 3) for x in s["trials_per_s_each"]]
        for key in ("driver_cpu_ms_per_trial", "idle_s_per_call", "non_trial_s_per_job", "trial_s_mean",
                    "trial_s_max", "worker_s_per_trial"):
            figures[f"{name}_{key}"] = round(s[key], 4)
    figures["steps_per_trial"] = round(ray["steps_per_trial"], 1)
    figures["ray_extra_idle_s_per_call"] = round(ray["idle_s_per_call"] - pool["idle_s_per_call"], 4)
    figures["ray_extra_driver_cpu_ms_per_trial"] = round(ray["driver_cpu_ms_per_trial"]
                                                         - pool["driver_cpu_ms_per_trial"], 4)
    # one driver process dispatches at most this many trials/s, were its work on one core
    figures["ray_driver_trials_per_s_max"] = round(1e3 / ray["driver_cpu_ms_per_trial"])
    return stats


def costs_of(figures: dict, stats: dict[str, dict], calls: dict[str, list[dict]], task: dict,
             protocol: dict, args: argparse.Namespace) -> dict[str, dict]:
    """Per task: the projection's trials, seconds per trial and per longest trial, load, idle, driver."""
    ray = stats["ray"]
    max_steps = int(task["session"]["max_steps"])
    per_step, per_step_source = step_seconds(calls["pool"] + calls["ray"], 1 / 179)
    # A job's object load: the pool's seconds outside trials (its per-trial messages cost ~nothing); what Ray
    # spends beyond that outside trials is per trial call (arguments, results), added to each trial.
    load_s = min(stats["pool"]["non_trial_s_per_job"], ray["non_trial_s_per_job"])
    per_job = args.trials / math.ceil(args.trials / math.ceil(args.trials / args.workers))
    ray_call_s = (ray["non_trial_s_per_job"] - load_s) / per_job
    figures.update(s_per_control_step=round(per_step, 5), s_per_control_step_from=per_step_source,
                   ray_call_s_per_trial=round(ray_call_s, 5))
    costs = {}
    for name, task_name, rate, long_factor, _source in DOCUMENTED:
        if task_name == "insertion":  # measured: Ray's own per-trial cost, and a trial at the episode's limit
            trial_s = ray["trial_s_mean"] + ray_call_s
            long_s = trial_s + max(max_steps - ray["steps_per_trial"], 0.0) * per_step
        else:  # documented pool rate with 2 workers: a worker's seconds per trial (loads, idle included)
            trial_s = 2.0 / rate + ray_call_s
            long_s = trial_s * long_factor
        costs[name] = {"trials": protocol["trials"][task_name], "trial_s": trial_s, "long_s": long_s,
                       "load_s": load_s, "idle_s": max(ray["idle_s_per_call"], 0.0),
                       "driver_s": ray["driver_cpu_ms_per_trial"] / 1e3}
    return costs


def _print(figures: dict, protocol: dict, projection: dict, args: argparse.Namespace) -> None:
    f = figures
    print(f"pool            {f['pool_trials_per_s']:.2f} trials/s ({args.workers} workers; calls "
          f"{', '.join(f'{x:.2f}' for x in f['pool_trials_per_s_each'])}); start-up {f['pool_startup_s']:.1f} s")
    print(f"ray             {f['ray_trials_per_s']:.2f} trials/s ({f['ray_actors']} actors; calls "
          f"{', '.join(f'{x:.2f}' for x in f['ray_trials_per_s_each'])}); start-up {f['ray_startup_s']:.1f} s "
          f"(connect {f['ray_connect_s']:.1f} s + actors {f['ray_actors_ready_s']:.1f} s)")
    print(f"ray / pool      {f['ray_over_pool']:.3f} (pairs of calls: {', '.join(map(str, f['ray_over_pool_each']))}); "
          f"outcomes {'identical' if f['same_outcomes'] else 'DIFFERENT'}")
    print(f"driver CPU      per trial: pool {f['pool_driver_cpu_ms_per_trial']:.2f} ms, ray "
          f"{f['ray_driver_cpu_ms_per_trial']:.2f} ms (one driver: <= {f['ray_driver_trials_per_s_max']} trials/s)")
    print(f"idle per call   pool {f['pool_idle_s_per_call']:.3f} s, ray {f['ray_idle_s_per_call']:.3f} s (wall - the "
          "workers' mean busy seconds)")
    print(f"outside trials  per job (object load, trial calls): pool {f['pool_non_trial_s_per_job']:.3f} s, ray "
          f"{f['ray_non_trial_s_per_job']:.3f} s; ray no-op actor call {f['ray_noop_call_ms_median']:.2f} ms")
    for name in ("pool", "ray"):
        pop = f["population"][name]
        print(f"population      {name}: {f['population']['candidates']} candidates x "
              f"{f['population']['trials_per_candidate']} trials, one call {pop['trials_per_s_one_call']:.2f} trials/s, "
              f"a call per candidate {pop['trials_per_s_call_per_candidate']:.2f}: "
              f"{pop['one_call_over_call_per_candidate']:.3f}x; outcomes "
              f"{'identical' if pop['same_outcomes'] else 'DIFFERENT'}")
    print(f"PROJECTION (computed, not measured): paper protocol per object-policy pair: nominal + population "
          f"{protocol['population']} x {protocol['iterations']} iterations x the task's trials + {1 + protocol['top_k']} "
          f"shapes x {args.confirm_trials} confirmation trials, {args.cores_per_node} cores per node, one worker per "
          "core; low-high: mean trials - one trial per chunk at the episode limit")
    names = list(projection)
    for mode, label in (("population", "as GRT runs: a whole population per evaluate call"),
                        ("per_candidate", "one candidate per evaluate call (GRT before 2026-11-25), for comparison")):
        print(f"  {label}:")
        print("  nodes workers | " + " | ".join(f"{n} ({projection[n]['trials']})" for n in names))
        for i, nodes in enumerate(NODES):
            row = [projection[n]["rows"][i] for n in names]
            print(f"  {nodes:5d} {row[0]['workers']:7d} | " + " | ".join(_span(x[f'{mode}_s']) for x in row))


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmark; prints progress, the figures, the projection and, last, one JSON line."""
    args = _arguments(argv)
    figures, calls, task = measure(args)
    stats = compare(figures, calls, args.workers)
    protocol = _protocol()
    costs = costs_of(figures, stats, calls, task, protocol, args)
    projection = project(costs, protocol, args.cores_per_node, args.confirm_trials, figures["ray_startup_s"])
    figures["projection"] = {
        "what": "PROJECTION computed from the figures above, not measured on a cluster",
        "cores_per_node": args.cores_per_node, "confirm_trials": args.confirm_trials, **protocol,
        "costs": {k: {kk: round(vv, 4) if isinstance(vv, float) else vv for kk, vv in v.items()}
                  for k, v in costs.items()},
        "sources": {name: source for name, *_, source in DOCUMENTED},
        "tasks": projection}
    figures["loadavg_after"] = _loadavg()
    _print(figures, protocol, projection, args)
    print(json.dumps(figures))
    return figures


if __name__ == "__main__":
    main()
