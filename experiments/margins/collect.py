"""Copy the records of the margins runs (``bash experiments/margins/run.sh``) into ``experiments/margins/runs``.

Per cell (a run folder under OUT): ``summary_<cell>.json``, ``run_config.yaml`` (the paths inside this repository
written relative to it, as the other committed records), ``curve.png``, ``shapes.png``,
the confirmation's and the shrink's journals (every fresh episode behind the confirmed drops and the shrunk
sizes), and its latest profile as ``profile_<cell>.json`` / ``profile_<cell>.png`` (the names
``python -m grt.report`` pairs with the summary). Files already here are replaced by the run's.

    python experiments/margins/collect.py outputs/margins
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]


def relative_paths(text: str) -> str:
    """``text`` with this repository's absolute paths written relative to its root."""
    return text.replace(f"{ROOT}/grt/../", "").replace(f"{ROOT}/", "")


def collect(out: Path) -> list[str]:
    """Copy every finished cell under ``out``; returns the cells copied."""
    done = []
    for run in sorted(p for p in out.iterdir() if (p / "summary.json").is_file()):
        dest = HERE / "runs" / run.name
        dest.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run / "summary.json", dest / f"summary_{run.name}.json")
        (dest / "run_config.yaml").write_text(relative_paths((run / "run_config.yaml").read_text()))
        for name in ("curve.png", "shapes.png", *(p.name for p in run.glob("confirm-*.jsonl")),
                     *(p.name for p in run.glob("shrink-*.jsonl"))):
            if (run / name).is_file():
                shutil.copyfile(run / name, dest / name)
        profiles = sorted(run.glob("profile/*/profile.json"), key=lambda p: p.stat().st_mtime)
        if profiles:
            shutil.copyfile(profiles[-1], dest / f"profile_{run.name}.json")
            shutil.copyfile(profiles[-1].with_name("profile.png"), dest / f"profile_{run.name}.png")
        done.append(run.name)
    return done


if __name__ == "__main__":
    if len(sys.argv) != 2 or not Path(sys.argv[1]).is_dir():
        sys.exit("usage: python experiments/margins/collect.py OUT   (the folder run.sh wrote, outputs/margins)")
    print("copied:", ", ".join(collect(Path(sys.argv[1]))) or "nothing (no finished run)")
