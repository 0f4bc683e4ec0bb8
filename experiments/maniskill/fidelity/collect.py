"""Copy the calibrations of run.sh from outputs/calibrate/fidelity/ beside this script and print their tables.

    .venv/bin/python experiments/maniskill/fidelity/collect.py            # copy what is there, print the tables
    .venv/bin/python experiments/maniskill/fidelity/collect.py --tables   # only print, from the copies here
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

HERE = Path(__file__).resolve().parent
RUNS = HERE.parents[2] / "outputs" / "calibrate" / "fidelity"
KEEP = ("calibration.json", "fidelity.png", "fidelity_actions_*.npy")


def copy() -> None:
    for record in sorted(RUNS.glob("*/*/calibration.json")):
        target = HERE / record.parent.relative_to(RUNS)
        target.mkdir(parents=True, exist_ok=True)
        for pattern in KEEP:
            for file in record.parent.glob(pattern):
                shutil.copy2(file, target / file.name)


def _open_loop(r: dict) -> str:
    f = r.get("fidelity")
    if not f:
        return "-"
    m = f["median"]
    return (f"{m['swap_max_mm']:.1f} mm / {m['swap_max_deg']:.1f} deg (nudge {m['nudge_max_mm']:.1f} mm / "
            f"{m['nudge_max_deg']:.1f} deg)")


def row(name: str, r: dict) -> str:
    if "stock" not in r:
        return f"| {name} | - | - | - | - | {_open_loop(r)} |"
    agree = sum(r["agree"])
    return (f"| {name} | {r['stock']['success_rate']:.3f} | {r['swap']['success_rate']:.3f} | "
            f"{r['agreement']:.3f} ({agree}/{len(r['agree'])}) | {r['mass_ratio']:.4f} | {_open_loop(r)} |")


def tables() -> None:
    for group in ("before", "after", "round"):
        files = sorted((HERE / group).glob("*/calibration.json"))
        if not files:
            continue
        print(f"\n{group}\n\n| task | stock success | swap success | per-seed agreement | mass ratio | "
              "open loop: median largest divergence (median nudge floor) |\n|---|---|---|---|---|---|")
        for file in files:
            print(row(file.parent.name, json.loads(file.read_text())))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tables", action="store_true", help="only print the tables of the copies here")
    if not parser.parse_args().tables:
        copy()
    tables()


if __name__ == "__main__":
    main()
