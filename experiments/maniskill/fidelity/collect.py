"""Copy the calibrations of run.sh from outputs/calibrate/fidelity/ beside this script and print their tables.

    .venv/bin/python experiments/maniskill/fidelity/collect.py            # copy what is there, print the tables
    .venv/bin/python experiments/maniskill/fidelity/collect.py --tables   # only print, from the copies here
    .venv/bin/python experiments/maniskill/fidelity/collect.py --docs     # the short table of docs/maniskill-calibration.md
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
RUNS = ROOT / "outputs" / "calibrate" / "fidelity"
KEEP = ("calibration.json", "fidelity.png", "fidelity_actions_*.npy")
#: the swapped actor's stock collision records, by task (round: one sphere)
KIND = {"pick_cube": "box", "push_cube": "box", "pull_cube": "box", "stack_cube": "box", "lift_peg_upright": "box",
        "peg_insertion_side": "box", "poke_cube": "box", "plug_charger": "3 boxes", "pull_cube_tool": "2 boxes",
        "push_t": "2 boxes", "place_sphere": "sphere", "roll_ball": "sphere"}


def copy() -> None:
    """Copy each finished run's files here; paths inside the checkout become relative to its root."""
    for record in sorted(RUNS.glob("*/*/calibration.json")):
        target = HERE / record.parent.relative_to(RUNS)
        target.mkdir(parents=True, exist_ok=True)
        for pattern in KEEP:
            for file in record.parent.glob(pattern):
                shutil.copy2(file, target / file.name)
        (target / record.name).write_text(record.read_text().replace(f"{ROOT}/", ""))


def _open_loop(r: dict) -> str:
    f = r.get("fidelity")
    if not f:
        return "-"
    m = f["median"]
    return (f"{m['swap_max_mm']:.1f} mm / {m['swap_max_deg']:.1f} deg (nudge {m['nudge_max_mm']:.1f} mm / "
            f"{m['nudge_max_deg']:.1f} deg)")


def _task(name: str) -> str:
    return next((t for t in sorted(KIND, key=len, reverse=True) if name.startswith(t)), name)


def row(name: str, r: dict) -> str:
    """One table row: per-seed agreement compares outcome labels (the failure mode, success included);
    success agreement compares success alone."""
    kind = KIND.get(_task(name), "?")
    if "stock" not in r:
        return f"| {name} | {kind} | - | - | - | - | {r.get('mass_ratio', '-')} | {_open_loop(r)} |"
    agree = sum(r["agree"])
    same = sum((a == "success") == (b == "success") for a, b in zip(r["stock"]["modes"], r["swap"]["modes"], strict=True))
    return (f"| {name} | {kind} | {r['stock']['success_rate']:.3f} | {r['swap']['success_rate']:.3f} | "
            f"{r['agreement']:.3f} ({agree}/{len(r['agree'])}) | {same}/{len(r['agree'])} | {r['mass_ratio']:.4f} | "
            f"{_open_loop(r)} |")


def tables() -> None:
    for group in ("after", "round", "friction"):
        files = sorted((HERE / group).glob("*/calibration.json"))
        if not files:
            continue
        print(f"\n{group}\n\n| task | actor | stock success | swap success | per-seed agreement | same success | "
              "mass ratio | open loop: median largest divergence (median nudge floor) |\n|---|---|---|---|---|---|---|---|")
        for file in files:
            print(row(file.parent.name, json.loads(file.read_text())))


def hypotheses() -> None:
    """The table of hypotheses.json: per variant, the swapped tool's largest divergence in each replayed episode."""
    file = HERE / "hypotheses.json"
    if not file.is_file():
        return
    print("\n| variant | what it changes | largest divergence per episode (mm / deg) | median |\n|---|---|---|---|")
    for name, v in json.loads(file.read_text()).items():
        swap = [e["swap"] for e in v["episodes"]]
        per = ", ".join(f"{s['max_mm']:.1f} / {s['max_deg']:.1f}" for s in swap)
        mm, deg = (sorted(s[k] for s in swap) for k in ("max_mm", "max_deg"))
        mid = len(swap) // 2
        med = (f"{(mm[mid - 1] + mm[mid]) / 2:.1f} / {(deg[mid - 1] + deg[mid]) / 2:.1f}" if len(swap) % 2 == 0
               else f"{mm[mid]:.1f} / {deg[mid]:.1f}")
        print(f"| `{name}` | {v['what']} | {per} | {med} |")


def docs_table() -> None:
    """The short table of docs/maniskill-calibration.md, from after/."""
    print("| task | actor | success stock / swap | per-seed agreement (same success) | open loop mm / deg (nudge floor) |\n"
          "|---|---|---|---|---|")
    for file in sorted((HERE / "after").glob("*/calibration.json")):
        r, name = json.loads(file.read_text()), file.parent.name
        m = r["fidelity"]["median"]
        loop = f"{m['swap_max_mm']:.1f} / {m['swap_max_deg']:.1f} ({m['nudge_max_mm']:.1f} / {m['nudge_max_deg']:.1f})"
        if "stock" not in r:
            print(f"| `{name}` | {KIND.get(name, '?')} | no policy | - | {loop} |")
            continue
        same = sum((a == "success") == (b == "success") for a, b in zip(r["stock"]["modes"], r["swap"]["modes"], strict=True))
        print(f"| `{name}` | {KIND.get(name, '?')} | {r['stock']['success_rate']:.2f} / {r['swap']['success_rate']:.2f} | "
              f"{r['agreement']:.2f} ({same / len(r['agree']):.2f}) | {loop} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tables", action="store_true", help="only print the tables of the copies here")
    parser.add_argument("--docs", action="store_true", help="only print the docs page's table")
    args = parser.parse_args()
    if args.docs:
        docs_table()
        return
    if not args.tables:
        copy()
    tables()
    hypotheses()


if __name__ == "__main__":
    main()
