"""``python -m grt.report PATH [--csv OUT.csv]``: the paper's columns for a run or a multirun folder.

Reads only ``summary.json`` files (and ``error.txt`` of failed jobs), or the ``summary_<name>.json`` copies
that ``experiments/`` keeps of them, so a committed table renders as its sweep did: Final Drop (%), ΔComplexity,
Iter@50%, AUC, per run (with the confirmed Final Drop of runs that confirmed their CrashShapes on fresh
episodes, ``budget.confirm_trials``: the rank-1 drop and how many of the k drops are significant), plus
the mean over runs of each (selector, optimizer) method and σ, the way the paper aggregates objects into
Tables 1 and 2 (σ is part of the key: a folder that holds several σ does not average them together). S0 and the best score are in the task's own score, named
per run (``success rate``, ``mean opening (m)``); the other columns are relative to S0, unit-free.
A mistake (no such folder, no or a broken ``summary.json``, a ``--csv`` path that cannot be written) is
one ``error:`` line and exit code 2.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
from collections import defaultdict
from pathlib import Path

from grt.cli._common import exit_on_user_error, write_output
from grt.errors import check_output_file
from grt.scores import ScoreSpec

COLUMNS = ("task", "object", "policy", "selector", "optimizer", "sigma", "seed", "tau", "score_name",
           "score_unit", "s0", "best_score", "final_drop", "confirmed_final_drop", "delta_complexity", "iter_at_50", "auc",
           "evaluations", "invalid_candidates", "validity_checked", "wall_s")
REQUIRED = ("task", "object", "selector", "optimizer", "final_drop", "delta_complexity", "iter_at_50", "auc")


class ReportError(ValueError):
    """A folder or summary the report cannot read; the message names it and the fix."""


def collect(root: Path) -> tuple[list[dict], list[Path]]:
    """Summaries under ``root`` (itself a run folder, or any tree of them) and failed job folders.

    Raises:
        ReportError: ``root`` does not exist, or a ``summary.json`` is not a GRT run summary.
    """
    if not root.exists():
        raise ReportError(f"{root} does not exist; give a run folder or a multirun folder under outputs/")
    if root.is_file():
        if root.name != "summary.json":
            raise ReportError(f"{root} is a file; give a run folder or a multirun folder under outputs/")
        root = root.parent
    rows = []
    for path in sorted(p for p in root.rglob("summary*.json") if _is_summary_name(p.name)):
        data = read_summary(path)
        data["run"] = str(path.parent)
        spec = ScoreSpec.from_summary(data)  # summaries written before score_name: a success rate
        data.setdefault("score_name", spec.name)
        data.setdefault("score_unit", spec.unit)
        rows.append(data)
    failed = sorted(p.parent for p in root.rglob("error.txt"))
    return rows, failed


def _is_summary_name(name: str) -> bool:
    """``summary.json`` (a run folder) or ``summary_<name>.json`` (a copy kept under ``experiments/``)."""
    return name == "summary.json" or (name.startswith("summary_") and name.endswith(".json"))


def read_summary(path: Path) -> dict:
    """One run's ``summary.json``, refused with its path when it is not a finished GRT run's summary."""
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReportError(f"{path}: cannot read it ({exc}); delete or restore the file, or report on "
                          "another folder") from None
    missing = [k for k in REQUIRED if not isinstance(data, dict) or k not in data]
    if missing:
        raise ReportError(f"{path}: not a GRT run summary (no {', '.join(missing)}); report on folders "
                          "written by python -m grt.run")
    return data


def _fmt(v, kind: str = "") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if kind == "pct":
        return f"{100 * v:.1f}"
    if kind == "g":
        return f"{v:g}"
    return f"{v:.3f}" if isinstance(v, float) else str(v)


def score_cell(r: dict, key: str) -> str:
    """S0 or the best score of a run in its task's score (3 decimals for a success rate)."""
    spec = ScoreSpec.from_summary(r)
    return _fmt(r.get(key)) if spec.binary else spec.fmt(r.get(key))


def method(r: dict) -> str:
    """The paper's row label: handles + search, ``+ SS`` under a Smoothness-Score budget."""
    return f"{r['selector']} + {r['optimizer']}" + (" + SS" if r.get("tau") is not None else "")


def aggregate(rows: list[dict]) -> list[dict]:
    """Mean of each metric per (task, policy, method, σ), over objects/seeds (NaNs skipped)."""
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in rows:
        groups[(r["task"], r.get("policy") or "-", method(r), _fmt(r.get("sigma"), "g"))].append(r)
    out = []
    for (task, policy, label, sigma), rs in sorted(groups.items()):
        agg = {"task": task, "policy": policy, "method": label, "sigma": sigma, "runs": len(rs)}
        for k in ("final_drop", "confirmed_final_drop", "delta_complexity", "iter_at_50", "auc"):
            vals = [r[k] for r in rs if r.get(k) is not None and not (isinstance(r[k], float) and math.isnan(r[k]))]
            agg[k] = sum(vals) / len(vals) if vals else None
        out.append(agg)
    return out


def markdown(rows: list[dict], agg: list[dict], failed: list[Path]) -> str:
    """Per-run table, per-method table (the paper's columns) and the failed jobs."""
    confirmed = any(r.get("confirm") for r in rows)
    head, rule = ("| Confirmed drop (%) ", "---|") if confirmed else ("", "")
    lines = [f"| task | object | policy | method | σ | seed | score | S0 | best | Final Drop (%) ↑ {head}| ΔComplexity ↓ "
             f"| Iter@50% ↓ | AUC ↑ | implausible |", f"|---|---|---|---|---|---|---|---|---|---|{rule}---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['task']} | {r['object']} | {r.get('policy') or '-'} | {method(r)} | "
                     f"{_fmt(r.get('sigma'), 'g')} | {_fmt(r.get('seed'))} | "
                     f"{ScoreSpec.from_summary(r).label} | {score_cell(r, 's0')} | {score_cell(r, 'best_score')} | "
                     f"{_fmt(r['final_drop'], 'pct')} | {_confirm_cell(r) if confirmed else ''}"
                     f"{_fmt(r['delta_complexity'])} | "
                     f"{r['iter_at_50']}{'' if r.get('reached_50') else '*'} | {_fmt(r['auc'])} | {_implausible_cell(r)} |")
    lines += ["", "Mean per method (* = 50% drop not reached; T reported"
              + ("; confirmed drop: rank-1 CrashShape on fresh episodes, (n/k) drops significant" if confirmed else "")
              + "):", "",
              f"| task | policy | method | σ | runs | Final Drop (%) ↑ {head}| ΔComplexity ↓ | Iter@50% ↓ | AUC ↑ |",
              f"|---|---|---|---|---|---|{rule}---|---|---|"]
    for a in agg:
        cell = f"{_fmt(a['confirmed_final_drop'], 'pct')} | " if confirmed else ""
        lines.append(f"| {a['task']} | {a['policy']} | {a['method']} | {a['sigma']} | {a['runs']} | {_fmt(a['final_drop'], 'pct')} | "
                     f"{cell}{_fmt(a['delta_complexity'])} | {_fmt(a['iter_at_50'])} | {_fmt(a['auc'])} |")
    if failed:
        lines += ["", f"{len(failed)} failed job(s) (see error.txt):"] + [f"- {p}" for p in failed]
    return "\n".join(lines)


def _implausible_cell(r: dict) -> str:
    """``4 / 30``: candidates the validity checks refused (never simulated) of those the search made;
    ``not checked`` for a run with ``deformer.validity=false``."""
    if r.get("invalid_candidates") is None or r.get("evaluations") is None:
        return "-"  # a summary from before the checks were counted
    if r.get("validity_checked") is False:
        return "not checked"
    return f"{r['invalid_candidates']} / {r['evaluations'] - 1}"


def _confirm_cell(r: dict) -> str:
    """``41.7 (2/3)``: the rank-1 drop on fresh episodes and how many of the k drops are significant."""
    conf = r.get("confirm")
    if not conf:
        return "- | "
    return f"{_fmt(conf['confirmed_final_drop'], 'pct')} ({conf['confirmed']}/{len(conf['shapes'])}) | "


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m grt.report", description=__doc__.splitlines()[0])
    ap.add_argument("path", type=Path, help="a run folder or a multirun folder")
    ap.add_argument("--csv", type=Path, help="also write the per-run rows as CSV (into an existing folder)")
    args = ap.parse_args(argv)
    with exit_on_user_error(ReportError):
        if args.csv:
            check_output_file(args.csv, (".csv",), "--csv")  # before reading anything
        rows, failed = collect(args.path)
        if not rows and not failed:
            raise ReportError(f"no summary.json (or summary_<name>.json) under {args.path}: is it a finished GRT "
                              "run folder?")
        print(markdown(rows, aggregate(rows), failed))
        if args.csv:
            text = io.StringIO(newline="")
            w = csv.DictWriter(text, fieldnames=COLUMNS, extrasaction="ignore")
            w.writeheader()
            w.writerows(rows)
            write_output(args.csv, text.getvalue(), "--csv PATH")
            print(f"\nwrote {args.csv}")


if __name__ == "__main__":
    main()
