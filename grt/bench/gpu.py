"""Benchmark of evaluator=gpu: ``python -m grt.bench gpu STEP [--out DIR] [options]``.

Steps (each prints its figures and, last, one JSON line, and writes ``DIR/STEP.json``):

* ``nominal``: insertion_state's success on the nominal plug in GPU sub-scenes against the CPU worker
  pool's on the same seeds, each with its 95% Wilson interval (they should overlap, or the difference is
  the GPU's physics: its solver, the 64-vertex hulls on both, the controller's GPU IK);
* ``throughput``: trials/s of one population (the nominal plug and 3 deformed ones) at ``--sizes``
  sub-scenes (default 512 and 2048), the env's rebuild and the episodes timed apart, against the CPU pool's
  trials/s measured in the same run (``--cpu-trials``, ``--workers``);
* ``protocol``: the paper's insertion protocol (10 iterations x 10 candidates x 128 trials,
  ``budget=paper``) as one ``python -m grt.run ... evaluator=gpu``, its wall time and where it went;
* ``report``: ``DIR/gpu_check.png`` (the three figures) and ``DIR/gpu_check.md`` from the steps' JSON files.

``--backend physx_cpu`` runs each step's GPU part on ManiSkill's CPU simulation, one sub-scene per env
(tiny sizes only: what a machine without a GPU can check of this script).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from grt.bench.grasp import compose, deformed_candidates

STEPS = ("nominal", "throughput", "protocol", "report")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m grt.bench gpu", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("step", choices=STEPS)
    ap.add_argument("--out", default=None, help="folder for STEP.json (and the protocol's run folder)")
    ap.add_argument("--backend", default="physx_cuda", choices=("physx_cuda", "physx_cpu"))
    ap.add_argument("--policy", default="insertion_state", help="insertion policy config (default insertion_state)")
    ap.add_argument("--trials", type=int, default=128, help="nominal: trials on the GPU (default 128)")
    ap.add_argument("--cpu-trials", type=int, default=64, help="CPU pool trials (default 64; 0: skip the CPU)")
    ap.add_argument("--workers", type=int, default=2, help="CPU pool workers (default 2)")
    ap.add_argument("--sizes", default="512,2048", help="throughput: sub-scenes per env, comma-separated")
    ap.add_argument("--max-steps", type=int, default=None, help="control steps per episode (default: the task's)")
    ap.add_argument("--timeout", type=float, default=360.0, help="protocol: seconds before it is stopped")
    ap.add_argument("--budget", default="paper", help="protocol: budget config (default paper)")
    ap.add_argument("--overrides", default="", help="protocol: more grt.run overrides, space-separated")
    args = ap.parse_args(argv)
    out = Path(args.out) if args.out else None
    if args.step == "report":
        print(json.dumps(report(out or Path("."))))
        return
    figures = {"nominal": nominal, "throughput": throughput, "protocol": protocol}[args.step](args, out)
    figures = _save(args, out, figures)
    print(json.dumps(figures))


def _save(args, out: Path | None, figures: dict) -> dict:
    """``DIR/STEP.json`` with the step's figures so far (a step stopped at its time limit keeps what it had)."""
    figures = {"step": args.step, "backend": args.backend, "device": _device(args.backend), **figures}
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / f"{args.step}.json").write_text(json.dumps(figures, indent=1))
    return figures


def _device(backend: str) -> str:
    import torch

    return torch.cuda.get_device_name(0) if backend == "physx_cuda" and torch.cuda.is_available() else "cpu"


def _setup(args):
    from omegaconf import OmegaConf

    from grt.geometry.mesh import load_mesh

    overrides = ["task=insertion", f"policy={args.policy}", "object=usb_plug"]
    if args.max_steps:
        overrides.append(f"task.session.max_steps={args.max_steps}")
    cfg = compose(overrides)
    task, policy = (OmegaConf.to_container(cfg[k], resolve=True) for k in ("task", "policy"))
    return cfg, task, policy, load_mesh(cfg.object)


def _gpu(args, task, policy, mesh, max_envs: int):
    from grt.evaluators.gpu import GpuEvaluator

    return GpuEvaluator(task, policy, nominal=mesh, backend=args.backend, progress=False,
                        max_envs=1 if args.backend == "physx_cpu" else max_envs)


def _cpu_pool(args, task, policy, mesh, meshes, seeds) -> dict:
    """Trials/s and results of the CPU worker pool (after its start-up) on the same meshes and seeds."""
    from grt.evaluators.sim import SimEvaluator

    task = {**task, "session": {**task["session"], "render_backend": "none"}}  # no Vulkan needed; same physics
    with SimEvaluator(task=task, policy=policy, workers=args.workers, nominal=mesh, progress=False) as ev:
        begin = time.perf_counter()
        ev.start(say=None)
        startup = time.perf_counter() - begin
        begin = time.perf_counter()
        results = ev.evaluate(meshes, seeds)
        seconds = time.perf_counter() - begin
    return {"results": results, "startup_s": round(startup, 2), "seconds": round(seconds, 2),
            "trials_per_s": round(len(meshes) * len(seeds) / seconds, 3), "workers": args.workers}


def nominal(args, out) -> dict:
    """GPU vs CPU success of the policy on the nominal plug, same seeds."""
    from grt.metrics import wilson_interval
    from grt.redteam import episode_seeds

    cfg, task, policy, mesh = _setup(args)
    seeds = episode_seeds(int(cfg.budget.seed), args.trials)
    with _gpu(args, task, policy, mesh, args.trials) as ev:
        begin = time.perf_counter()
        gpu = ev.evaluate([mesh], seeds)[0]
        gpu_s, info = time.perf_counter() - begin, ev.backend_info()
    n = sum(1 for t in gpu.trials if t.mode != "sim_error")
    figures = {"policy": args.policy, "seeds": f"episode_seeds({int(cfg.budget.seed)}, n)",
               "gpu": {"trials": len(seeds), "success_rate": gpu.success_rate, "outcomes": gpu.outcomes,
                       "ci95": wilson_interval(gpu.success_rate * n, n) if n else None, "seconds": round(gpu_s, 2),
                       "mean_steps": float(np.mean([t.info.get("steps", 0) for t in gpu.trials])), "evaluator": info}}
    print(f"GPU ({_device(args.backend)}): success {gpu.success_rate:.3f} over "
          f"{len(seeds)} trials {gpu.outcomes} in {gpu_s:.1f} s")
    _save(args, out, figures)
    if args.cpu_trials:
        cpu = _cpu_pool(args, task, policy, mesh, [mesh], seeds[:args.cpu_trials])
        result = cpu.pop("results")[0]
        m = len(result.valid_trials)
        figures["cpu"] = {"trials": args.cpu_trials, "success_rate": result.success_rate, "outcomes": result.outcomes,
                          "ci95": wilson_interval(result.success_rate * m, m) if m else None, **cpu}
        same = [a.mode == b.mode for a, b in zip(gpu.trials, result.trials, strict=False)]
        both = [figures[k]["ci95"] or (float("nan"),) * 2 for k in ("gpu", "cpu")]
        low, high = max(both[0][0], both[1][0]), min(both[0][1], both[1][1])
        figures["intervals_overlap"] = bool(low <= high)
        figures["same_mode_fraction"] = round(float(np.mean(same)), 3)
        print(f"CPU pool: success {result.success_rate:.3f} over {args.cpu_trials} trials {result.outcomes}; "
              f"95% intervals {'overlap' if low <= high else 'do NOT overlap'}; same outcome on "
              f"{figures['same_mode_fraction']:.0%} of the shared seeds")
    return figures


def throughput(args, out) -> dict:
    """Trials/s of one population at each size, the rebuild and the episodes apart; the CPU pool's beside."""
    from grt.redteam import episode_seeds

    cfg, task, policy, mesh = _setup(args)
    meshes = [mesh, *deformed_candidates(mesh, 3, sigma=0.02)]
    rows = []
    for size in [int(s) for s in args.sizes.split(",") if s]:
        seeds = episode_seeds(7, max(1, size // len(meshes)))
        with _gpu(args, task, policy, mesh, size) as ev:
            begin = time.perf_counter()
            results = ev.evaluate(meshes, seeds)
            seconds = time.perf_counter() - begin
            info = ev.backend_info()
        trials = len(meshes) * len(seeds)
        steps = int(sum(t.info.get("steps", 0) for r in results for t in r.trials))
        row = {"sub_scenes": trials, "seconds": round(seconds, 2), "trials_per_s": round(trials / seconds, 2),
               "build_s": info["build_s"], "episodes_s": info["episodes_s"],
               "episode_trials_per_s": round(trials / info["episodes_s"], 2) if info["episodes_s"] else None,
               "env_steps_per_s": round(steps / info["episodes_s"], 1) if info["episodes_s"] else None,
               "success_rates": [round(r.success_rate, 3) for r in results], "gpu_free_mb": info["gpu_free_mb"]}
        rows.append(row)
        _save(args, out, {"policy": args.policy, "candidates": len(meshes), "sizes": rows})
        print(f"{trials:5d} sub-scenes: {row['trials_per_s']:.1f} trials/s ({seconds:.1f} s: rebuild "
              f"{row['build_s']:.1f} s, episodes {row['episodes_s']:.1f} s)")
    figures = {"policy": args.policy, "candidates": len(meshes), "sizes": rows}
    if args.cpu_trials:
        per = max(1, args.cpu_trials // len(meshes))
        cpu = _cpu_pool(args, task, policy, mesh, meshes, episode_seeds(7, per))
        cpu.pop("results")
        figures["cpu_pool"] = cpu
        best = max(r["trials_per_s"] for r in rows)
        figures["speedup_vs_cpu_pool"] = round(best / cpu["trials_per_s"], 1)
        print(f"CPU pool ({args.workers} workers): {cpu['trials_per_s']:.2f} trials/s; the GPU's best is "
              f"{figures['speedup_vs_cpu_pool']}x that")
    return figures


def protocol(args, out) -> dict:
    """The paper's insertion protocol as one red-team run on evaluator=gpu; its wall time and breakdown."""
    run_dir = (out or Path("outputs/bench_gpu")) / "protocol_run"
    command = [sys.executable, "-m", "grt.run", "task=insertion", f"policy={args.policy}", "selector=manual",
               f"budget={args.budget}", "budget.videos=0", "evaluator=gpu", f"evaluator.backend={args.backend}",
               f"hydra.run.dir={run_dir}", *(["evaluator.max_envs=1"] if args.backend == "physx_cpu" else []),
               *args.overrides.split()]
    print(" ".join(command[1:]), flush=True)
    begin = time.perf_counter()
    try:
        proc = subprocess.run(command, capture_output=True, text=True, timeout=args.timeout)
        code, tail = proc.returncode, (proc.stdout + proc.stderr)[-3000:]
    except subprocess.TimeoutExpired as err:
        code, tail = None, str((err.stdout or b"")[-3000:])
    wall = time.perf_counter() - begin
    journal = run_dir / "journal.jsonl"
    done = len(journal.read_text().splitlines()) if journal.exists() else 0
    summary = json.loads((run_dir / "summary.json").read_text()) if (run_dir / "summary.json").exists() else {}
    figures = {"command": " ".join(command[2:]), "budget": args.budget, "exit_code": code, "wall_s": round(wall, 1),
               "candidates_journaled": done, "timed_out": code is None,
               "summary": {k: summary.get(k) for k in ("s0", "best_score", "final_drop", "wall_s", "evaluator",
                                                        "timings")}, "log_tail": tail}
    print(f"protocol: exit {code}, {done} candidates journaled in {wall:.0f} s"
          f"{' (stopped at the timeout)' if code is None else ''}")
    return figures


TARGET_S = 300.0  # the must: the paper's insertion protocol in <= 5 minutes per object-policy pair


def report(out: Path) -> dict:
    """``gpu_check.png`` and ``gpu_check.md`` in ``out`` from the steps' JSON files there (missing ones skipped)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    found = {s: json.loads((out / f"{s}.json").read_text()) for s in STEPS[:3] if (out / f"{s}.json").exists()}
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    lines = [f"# GPU check ({next((f['device'] for f in found.values()), '?')})", ""]
    nom = found.get("nominal")
    if nom:
        sides = [k for k in ("gpu", "cpu") if nom.get(k, {}).get("ci95")]
        rates = [nom[k]["success_rate"] for k in sides]
        errs = np.array([[r - nom[k]["ci95"][0], nom[k]["ci95"][1] - r] for k, r in zip(sides, rates, strict=True)]).T
        axes[0].bar([f"{k.upper()} ({nom[k]['trials']})" for k in sides], rates, yerr=errs, capsize=6,
                    color=["tab:green", "tab:blue"][:len(sides)])
        axes[0].set_ylim(0, 1.05)
        for k in sides:
            lines.append(f"- nominal success {k.upper()}: {nom[k]['success_rate']:.3f} over {nom[k]['trials']} trials, "
                         f"95% [{nom[k]['ci95'][0]:.3f}, {nom[k]['ci95'][1]:.3f}], {nom[k]['outcomes']}")
        if "intervals_overlap" in nom:
            lines.append(f"- intervals overlap: {nom['intervals_overlap']}; same outcome on "
                         f"{nom['same_mode_fraction']:.0%} of the shared seeds")
    axes[0].set_title(f"nominal success ({(nom or {}).get('policy', '?')})")
    thr = found.get("throughput")
    if thr:
        sizes = [r["sub_scenes"] for r in thr["sizes"]]
        axes[1].plot(sizes, [r["trials_per_s"] for r in thr["sizes"]], "o-", label="GPU (with rebuild)")
        axes[1].plot(sizes, [r["episode_trials_per_s"] or 0 for r in thr["sizes"]], "s--", label="GPU episodes only")
        if "cpu_pool" in thr:
            axes[1].axhline(thr["cpu_pool"]["trials_per_s"], color="tab:blue",
                            label=f"CPU pool ({thr['cpu_pool']['workers']} workers)")
        axes[1].set_xscale("log")
        axes[1].set_yscale("log")
        axes[1].set_xlabel("sub-scenes per env")
        axes[1].legend(fontsize=8)
        for r in thr["sizes"]:
            lines.append(f"- {r['sub_scenes']} sub-scenes: {r['trials_per_s']} trials/s (rebuild {r['build_s']} s, "
                         f"episodes {r['episodes_s']} s, {r['env_steps_per_s']} env steps/s)")
        if "cpu_pool" in thr:
            lines.append(f"- CPU pool: {thr['cpu_pool']['trials_per_s']} trials/s ({thr['cpu_pool']['workers']} workers);"
                         f" GPU best {thr.get('speedup_vs_cpu_pool')}x")
    axes[1].set_title("trials/s")
    pro = found.get("protocol")
    if pro:
        axes[2].bar(["protocol"], [pro["wall_s"]], color="tab:red" if pro["wall_s"] > TARGET_S else "tab:green")
        axes[2].axhline(TARGET_S, color="k", ls="--", label="5 min (must)")
        axes[2].axhline(60.0, color="gray", ls=":", label="1 min (aim)")
        axes[2].legend(fontsize=8)
        lines.append(f"- paper protocol: {pro['candidates_journaled']} candidates journaled in {pro['wall_s']} s "
                     f"(exit {pro['exit_code']}{', stopped at the timeout' if pro['timed_out'] else ''})")
    axes[2].set_title(f"red-team run, {(pro or {}).get('budget', 'paper')} budget: wall (s)")
    fig.tight_layout()
    fig.savefig(out / "gpu_check.png", dpi=110)
    plt.close(fig)
    (out / "gpu_check.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return {"step": "report", "figure": str(out / "gpu_check.png"), "steps": sorted(found)}


if __name__ == "__main__":
    main()
