"""Record red-team journals of the demo and of one small run per task, and compare two recordings trial for trial.

A change to how trials are simulated (the episode protocol, the evaluators) must leave every CPU trial as it
was: record the runs before the change and after it, then compare (every candidate's mesh hash and score, every
trial's seed, mode and score, every confirmation trial)::

    PYTHONPATH=$PWD python scripts/trial_parity.py record /tmp/parity/before     # at the base commit
    PYTHONPATH=$PWD python scripts/trial_parity.py record /tmp/parity/after      # with the change
    python scripts/trial_parity.py compare /tmp/parity/before /tmp/parity/after

``--only NAME,...`` records some of the runs; ``--skip NAME,...`` leaves some out. Each run's folder is
``OUT/<name>``; a run whose folder has a ``summary.json`` already is not run again. ``compare`` exits 1 when
a trial differs, 2 when a run is missing on one side. ``twin`` names pairs of runs that must agree with each
other although their commands differ (the GPU evaluator's path on ``physx_cpu`` against the worker pool).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

#: name -> the ``python -m grt.run`` overrides (small budgets; the demo is the default command)
RUNS: dict[str, list[str]] = {
    "demo": [],
    "grasp_smoke": ["budget=smoke", "task=grasp_2cam", "policy=antipodal"],
    "insertion": ["task=insertion", "policy=insertion_state", "budget=smoke", "budget.trials=4"],
    "drawer": ["task=drawer", "policy=drawer_state", "budget=smoke", "budget.trials=2"],
    "push_cube_ppo": ["task=push_cube", "policy=push_cube_state", "budget=smoke", "budget.trials=4",
                      "budget.confirm_trials=4"],
    "pick_cube_expert": ["task=pick_cube", "policy=pick_cube_expert", "budget=smoke", "budget.trials=4"],
    "pick_cube_planner": ["task=pick_cube", "policy=motion_planner", "task.session.control_mode=pd_joint_pos",
                          "budget=smoke", "budget.trials=3"],
    "push_cube_bent": ["task=push_cube", "policy=push_cube_expert", "budget=smoke", "budget.trials=6",
                       "budget.sigma=0.3", "deformer.validity=false"],
    "pick_cube_planner_bent": ["task=pick_cube", "policy=motion_planner", "task.session.control_mode=pd_joint_pos",
                               "budget=smoke", "budget.trials=3", "budget.sigma=0.3", "deformer.validity=false"],
    "insertion_racing": ["task=insertion", "policy=insertion_servo", "budget=smoke", "budget.trials=8",
                         "budget.population=4", "budget.racing=true", "budget.race_rounds=4",
                         "task.session.max_steps=80", "task.crash_margin=0.01"],
    "insertion_race_stops": ["task=insertion", "policy=insertion_servo", "budget=smoke", "budget.trials=8",
                             "budget.racing=true", "budget.race_rounds=4", "budget.race_alpha=0.45",
                             "task.session.max_steps=80"],
    "insertion_gpu_cpu": ["task=insertion", "policy=insertion_servo", "evaluator=gpu", "evaluator.backend=physx_cpu",
                          "evaluator.max_envs=1", "budget=smoke", "budget.trials=3", "task.session.max_steps=80"],
}
#: runs whose trials must equal another run's (same search, another evaluator)
GPU_ON_CPU = ["evaluator=gpu", "evaluator.backend=physx_cpu", "evaluator.max_envs=1"]
TWINS = {"insertion_gpu_racing": ("insertion_racing", GPU_ON_CPU),
         "insertion_gpu_race_stops": ("insertion_race_stops", GPU_ON_CPU)}


def _commands(names: list[str]) -> dict[str, list[str]]:
    out = {}
    for name in names:
        if name in RUNS:
            out[name] = RUNS[name]
        elif name in TWINS:
            base, extra = TWINS[name]
            out[name] = [*RUNS[base], *extra]
        else:
            raise SystemExit(f"unknown run {name!r}; known: {', '.join([*RUNS, *TWINS])}")
        if name != "demo":  # every run goes through the whole loop, whatever its nominal scores
            out[name] = [*out[name], "task.nominal_floor=null"]
    return out


def record(out: Path, names: list[str]) -> None:
    """Run each named run into ``out/<name>`` (skipping finished ones), printing its seconds."""
    out.mkdir(parents=True, exist_ok=True)
    for name, overrides in _commands(names).items():
        folder = out / name
        if (folder / "summary.json").is_file():
            print(f"{name}: done already", flush=True)
            continue
        begin = time.perf_counter()
        cmd = [sys.executable, "-m", "grt.run", *overrides, f"hydra.run.dir={folder}"]
        with (out / f"{name}.log").open("w") as log:
            rc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode
        print(f"{name}: exit {rc} in {time.perf_counter() - begin:.0f} s ({' '.join(overrides) or 'the demo'})",
              flush=True)


def _journal(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _trials(records: list[dict]) -> list[tuple]:
    """Per candidate: (iteration, candidate, mesh hash, score, [(seed, mode, score)])."""
    return [(r.get("iteration"), r.get("candidate"), r.get("mesh_hash"), r.get("score"),
             [(t["seed"], t["mode"], t["score"]) for t in r.get("trials") or []]) for r in records]


def compare_runs(a: Path, b: Path) -> list[str]:
    """Differences between two run folders' journals (and confirmation journals), one line each."""
    diffs = []
    files = sorted({p.name for p in (*a.glob("journal.jsonl"), *a.glob("confirm-*.jsonl"),
                                     *b.glob("journal.jsonl"), *b.glob("confirm-*.jsonl"))})
    for name in files:
        if not (a / name).is_file() or not (b / name).is_file():
            diffs.append(f"{name}: only in {'the first' if (a / name).is_file() else 'the second'}")
            continue
        ta, tb = _trials(_journal(a / name)), _trials(_journal(b / name))
        if len(ta) != len(tb):
            diffs.append(f"{name}: {len(ta)} against {len(tb)} records")
        for ra, rb in zip(ta, tb, strict=False):
            if ra != rb:
                diffs.append(f"{name}: iteration {ra[0]} candidate {ra[1]}: {ra[2:]} != {rb[2:]}")
    return diffs


def count(folder: Path) -> tuple[int, int]:
    """(candidates, trials) of a run's journal and confirmation journals."""
    records = [r for p in [*folder.glob("journal.jsonl"), *folder.glob("confirm-*.jsonl")] for r in _journal(p)]
    return len(records), sum(len(r.get("trials") or []) for r in records)


def compare(first: Path, second: Path, names: list[str]) -> int:
    missing = bad = 0
    for name in names:
        base = TWINS[name][0] if name in TWINS else name
        a, b = first / base, second / name
        if not (a / "journal.jsonl").is_file() or not (b / "journal.jsonl").is_file():
            print(f"{name}: missing ({a} or {b} has no journal)")
            missing += 1
            continue
        diffs = compare_runs(a, b)
        candidates, trials = count(a)
        print(f"{name}{f' (against {base})' if base != name else ''}: "
              f"{'IDENTICAL' if not diffs else f'{len(diffs)} DIFFERENCES'} ({candidates} records, {trials} trials)")
        for line in diffs[:20]:
            print("   ", line)
        bad += bool(diffs)
    return 1 if bad else (2 if missing else 0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    rec = sub.add_parser("record")
    rec.add_argument("out", type=Path)
    cmp = sub.add_parser("compare")
    cmp.add_argument("first", type=Path)
    cmp.add_argument("second", type=Path)
    for p in (rec, cmp):
        p.add_argument("--only", default="")
        p.add_argument("--skip", default="")
    args = parser.parse_args()
    names = [n for n in (args.only.split(",") if args.only else list(RUNS)) if n]
    names = [n for n in names if n not in args.skip.split(",")]
    if args.what == "record":
        record(args.out, names)
    else:
        sys.exit(compare(args.first, args.second, names))


if __name__ == "__main__":
    main()
