"""Copy the benchmark's run summaries here (``summary_<object>_<optimizer>[_racing]_seed<S>.json`` per task
folder), so ``python -m grt.report experiments/search/<task>`` renders the table from committed files.

A summary written before ``summary.json`` carried trial counts gets them from its own run's journal and
confirmation (:func:`grt.racing.search_figures`, the function that writes them today). Usage::

    python experiments/search/collect.py OUT              # OUT: run.sh's folder of run folders -> <task>/
    python experiments/search/collect.py RUN_DIR demo     # -> demo/ (the demo with racing off and on)
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from grt.journal import Journal
from grt.racing import search_figures

HERE = Path(__file__).resolve().parent


def main(out: Path, into: str | None = None) -> None:
    copied = 0
    for path in sorted(out.rglob("summary.json")):
        summary = json.loads(path.read_text())
        if "trials_curve" not in summary:
            summary.update(search_figures(Journal(path.parent / "journal.jsonl").records, summary.get("confirm")))
        method = summary["optimizer"] + ("_racing" if summary.get("racing") else "")
        folder = HERE / (into or summary["task"])
        folder.mkdir(exist_ok=True)
        name = f"summary_{summary['object']}_{method}_seed{summary['seed']}.json"
        (folder / name).write_text(json.dumps(summary, indent=1, allow_nan=True) + "\n")
        copied += 1
    failed = sorted(p.parent for p in out.rglob("error.txt"))
    print(f"copied {copied} summaries into {HERE}" + "".join(f"\nfailed: {p}" for p in failed))


if __name__ == "__main__":
    main(Path(sys.argv[1]), *sys.argv[2:3])
