"""Which grasp CrashShapes cannot stand: each shape settled on the table before any policy acts.

A grasp trial rebuilds its scene, drops the object 1 mm onto the table and lets it settle; only then does the
policy see it. A deformed object whose base no longer holds it upright falls over there, and every grasp
policy then fails alike (``missed``): its "CrashShape" measures the shape's stability, not the policy. For
each grasp run folder given, this settles the nominal object, every CrashShape and every shrunk CrashShape
(``crashshapes/*_smallest.stl``) on the run's confirmation episodes (``GraspSession.rest_pose``; the tilt
is the angle between the object's up axis and the world's, it is placed upright) and writes one JSON line
per shape to stdout, then a table on stderr.

    python experiments/margins/standing.py outputs/margins/grasp_* --seeds 16 > experiments/margins/standing.jsonl

A shape counts as fallen in an episode when, ``--hold`` control steps after the trial's settle (200), it tilts
more than ``--fallen`` degrees (30).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import trimesh

from grt.rerun import RunReplayer


def shapes(run: Path) -> list[tuple[str, Path | None]]:
    """``(name, STL)`` of the nominal object (``None``: the run's own) and every CrashShape file of ``run``."""
    files = sorted((run / "crashshapes").glob("rank*.stl"))
    return [("nominal", None), *((f.stem, f) for f in files)]


def settle(replayer: RunReplayer, stl: Path | None, seeds: list[int], fallen: float, hold: int) -> dict:
    """The shape's rest poses on ``seeds``: per episode the tilt (deg) and spin (deg/s) when the policy would
    look, the tilt after ``hold`` control steps more, how many fell (held tilt above ``fallen``)."""
    mesh = replayer.nominal if stl is None else trimesh.load(stl, process=False, force="mesh")
    session = replayer.session()
    session.load_object(mesh, replayer.collision.parts(mesh))
    poses = [session.rest_pose(seed, hold=hold) for seed in seeds]
    held = [p["held_tilt_deg"] for p in poses]
    return {"tilt_deg": [p["tilt_deg"] for p in poses], "spin_dps": [p["spin_dps"] for p in poses],
            "held_tilt_deg": held, "fallen": int(sum(t > fallen for t in held)), "episodes": len(poses),
            "median_tilt_deg": float(np.median([p["tilt_deg"] for p in poses])),
            "median_spin_dps": float(np.median([p["spin_dps"] for p in poses])),
            "median_held_tilt_deg": float(np.median(held))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="grasp run folders (with crashshapes/)")
    parser.add_argument("--seeds", type=int, default=16, help="the first N of the run's confirmation episodes")
    parser.add_argument("--fallen", type=float, default=30.0, help="tilt (deg) above which a shape fell over")
    parser.add_argument("--hold", type=int, default=200, help="control steps after the trial's settle (where it ends up)")
    args = parser.parse_args(argv)
    rows = []
    for run in args.runs:
        summary = json.loads((run / "summary.json").read_text())
        if summary.get("task") != "grasp" or not (run / "crashshapes").is_dir():
            print(f"{run}: not a grasp run with CrashShapes, skipped", file=sys.stderr)
            continue
        seeds = [int(s) for s in (summary.get("confirm") or {}).get("seeds", [])][: args.seeds]
        replayer = RunReplayer(run, here=True)
        try:
            for name, stl in shapes(run):
                row = {"run": run.name, "object": summary["object"], "policy": summary.get("policy"),
                       "shape": name, **settle(replayer, stl, seeds, args.fallen, args.hold)}
                print(json.dumps(row), flush=True)
                rows.append(row)
        finally:
            replayer.close()
    print(f"{'run':32s} {'shape':24s} fallen  median: tilt, spin when the policy looks; tilt held", file=sys.stderr)
    for r in rows:
        print(f"{r['run']:32s} {r['shape']:24s} {r['fallen']:2d}/{r['episodes']:<3d} {r['median_tilt_deg']:6.1f} deg "
              f"{r['median_spin_dps']:7.1f} deg/s {r['median_held_tilt_deg']:6.1f} deg", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
