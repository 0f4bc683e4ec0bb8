"""The paper's columns for a run or a multirun folder (the library behind ``python -m grt.report``).

Reads only ``summary.json`` files (and ``error.txt`` of failed jobs), or the ``summary_<name>.json`` copies
that ``experiments/`` keeps of them, so a committed table renders as its sweep did: Final Drop (%), ΔComplexity,
Iter@50%, AUC, per run (with the confirmed Final Drop of runs that confirmed their CrashShapes on fresh
episodes, ``budget.confirm_trials``: the rank-1 drop and how many of the k drops are significant), plus
the mean over runs of each (selector, optimizer) method and σ, the way the paper aggregates objects into
Tables 1 and 2 (σ is part of the key: a folder that holds several σ does not average them together). S0 and the best score are in the task's own score, named
per run (``success rate``, ``mean opening (m)``); the other columns are relative to S0, unit-free.
Blue-team tables (``table3*.json``, written by ``python -m grt.blueteam``) render in the paper's Table 3
columns. A README keeps a generated table between ``<!-- grt.report PATH [--records] -->`` and
``<!-- /grt.report -->`` (``PATH`` relative to the README's folder); :func:`update_readmes` rewrites those
blocks from the files, so a committed table is never typed by hand.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
import shlex
from collections import defaultdict
from pathlib import Path

from grt.errors import UserError
from grt.fileio import write_text_atomic
from grt.report import figures
from grt.scores import ScoreSpec

COLUMNS = ("task", "object", "policy", "selector", "optimizer", "sigma", "seed", "tau", "score_name",
           "score_unit", "s0", "best_score", "final_drop", "confirmed_final_drop", "delta_complexity", "iter_at_50", "auc",
           "evaluations", "invalid_candidates", "validity_checked", "wall_s")
REQUIRED = ("task", "object", "selector", "optimizer", "final_drop", "delta_complexity", "iter_at_50", "auc")


class ReportError(UserError):
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
        data["file"] = str(path)
        spec = ScoreSpec.from_summary(data)  # summaries written before score_name: a success rate
        data.setdefault("score_name", spec.name)
        data.setdefault("score_unit", spec.unit)
        rows.append(data)
    failed = sorted(p.parent for p in root.rglob("error.txt"))
    return rows, failed


def unfinished(root: Path) -> list[Path]:
    """The red-team run folders under ``root`` (a sweep's jobs; ``root`` itself is not counted) that never
    wrote ``summary.json`` and hold no ``error.txt``: killed, stopped or still running. A run folder is one
    with the run's record (``run_config.yaml``) or Hydra's record of a ``grt.run`` job (a job stopped before
    its record was saved); one holding a kept copy ``summary_<name>.json`` (``experiments/``) is finished."""
    found = {p.parent for p in root.rglob("run_config.yaml")}
    found |= {p.parent.parent for p in root.rglob(".hydra/hydra.yaml") if _is_run_job(p)}
    return sorted(p for p in found if p != root and not any(_is_summary_name(f.name) for f in p.glob("summary*.json"))
                  and not (p / "error.txt").exists() and ".submitit" not in p.parts)


def _is_run_job(hydra_yaml: Path) -> bool:
    """Whether Hydra's record names the job ``run`` (``grt.run``'s; its log is ``run.log``)."""
    try:
        text = hydra_yaml.read_text()
    except OSError:
        return False
    return re.search(r"^    name: run$", text, re.MULTILINE) is not None  # hydra.job.name


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
    """The paper's row label: handles + search, ``+ SS`` under a Smoothness-Score budget (``+ size λ``: a search
    for the smallest CrashShape, ``budget.size_penalty``)."""
    return f"{r['selector']} + {r['optimizer']}" + (" + SS" if r.get("tau") is not None else "") + \
        (" + racing" if r.get("racing") else "") + (f" + size {r['size_penalty']:g}" if r.get("size_penalty") else "")


def aggregate(rows: list[dict]) -> list[dict]:
    """Mean of each metric per (task, policy, method, σ), over objects/seeds (NaNs skipped)."""
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in rows:
        groups[(r["task"], r.get("policy") or "-", method(r), _fmt(r.get("sigma"), "g"))].append(r)
    out = []
    for (task, policy, label, sigma), rs in sorted(groups.items()):
        agg = {"task": task, "policy": policy, "method": label, "sigma": sigma, "runs": len(rs)}
        for k in ("final_drop", "confirmed_final_drop", "noise_floor", "delta_complexity", "iter_at_50", "auc"):
            vals = [(figures.floor_of(r) or {}).get("mean") if k == "noise_floor" else r.get(k) for r in rs]
            vals = [v for v in vals if v is not None and not (isinstance(v, float) and math.isnan(v))]
            agg[k] = sum(vals) / len(vals) if vals else None
        out.append(agg)
    return out


def markdown(rows: list[dict], agg: list[dict], failed: list[Path], waiting: list[Path] = ()) -> str:
    """Per-run table, per-method table (the paper's columns), the failed jobs and those that never finished
    (``waiting``, :func:`unfinished`). The confirmed drop leads (the rank-1 CrashShape on fresh episodes, its
    paired 95% interval, Holm p and how many of the k drops held); Final Drop has its noise floor beside it."""
    lines = ["| task | object | policy | method | σ | seed | score | Confirmed drop (%) ↑ | S0 | best | Final Drop (%) ↑ "
             "| noise floor (%) | ΔComplexity ↓ | Iter@50% ↓ | AUC ↑ | implausible |", "|" + "---|" * 16]
    for r in rows:
        lines.append(f"| {r['task']} | {r['object']} | {r.get('policy') or '-'} | {method(r)} | "
                     f"{_fmt(r.get('sigma'), 'g')} | {_fmt(r.get('seed'))} | "
                     f"{ScoreSpec.from_summary(r).label} | {_confirm_cell(r)} | {score_cell(r, 's0')} | "
                     f"{score_cell(r, 'best_score')}{' (no CrashShape)' if r.get('crashshape_found') is False else ''} | "
                     f"{_fmt(r['final_drop'], 'pct')} | {_floor_cell(r)} | {_fmt(r['delta_complexity'])} | "
                     f"{r['iter_at_50']}{'' if r.get('reached_50') else '*'} | {_fmt(r['auc'])} | {_implausible_cell(r)} |")
    lines += ["", "Confirmed drop: the rank-1 CrashShape's drop on fresh episodes [paired 95% interval], Holm p, "
              "(n/k: drops confirmed of the k CrashShapes re-scored); noise floor: the mean (95th percentile) Final Drop of the "
              "same search if no deformation mattered (docs/reading-results.md).", "",
              "Mean per method (* = 50% drop not reached; T reported):", "",
              "| task | policy | method | σ | runs | Confirmed drop (%) ↑ | Final Drop (%) ↑ | noise floor (%) "
              "| ΔComplexity ↓ | Iter@50% ↓ | AUC ↑ |", "|" + "---|" * 11]
    for a in agg:
        lines.append(f"| {a['task']} | {a['policy']} | {a['method']} | {a['sigma']} | {a['runs']} | "
                     f"{_fmt(a['confirmed_final_drop'], 'pct')} | {_fmt(a['final_drop'], 'pct')} | "
                     f"{_fmt(a['noise_floor'], 'pct')} | {_fmt(a['delta_complexity'])} | {_fmt(a['iter_at_50'])} | "
                     f"{_fmt(a['auc'])} |")
    if failed:
        lines += ["", f"{len(failed)} failed job(s) (see error.txt):"] + [f"- {p}" for p in failed]
    if waiting:
        lines += ["", f"{len(waiting)} unfinished job(s) (no summary.json: killed, stopped or still running; "
                      "continue each with python -m grt.run resume=DIR):"] + [f"- {p}" for p in waiting]
    return "\n".join(lines)


def _floor_cell(r: dict) -> str:
    """``25.1 (62.5)``: the noise floor's mean and 95th percentile of a run (:func:`grt.report.figures.floor_of`)."""
    floor = figures.floor_of(r)
    return "-" if floor is None else f"{_fmt(floor['mean'], 'pct')} ({_fmt(floor['q95'], 'pct')})"


def _implausible_cell(r: dict) -> str:
    """``4 / 30``: candidates the validity checks refused (never simulated) of those the search made;
    ``not checked`` for a run with ``deformer.validity=false``."""
    if r.get("invalid_candidates") is None or r.get("evaluations") is None:
        return "-"  # a summary from before the checks were counted
    if r.get("validity_checked") is False:
        return "not checked"
    return f"{r['invalid_candidates']} / {r['evaluations'] - 1}"


def _confirm_cell(r: dict) -> str:
    """``77.8 [60.1, 90.2] p=0.001 (2/3)``: the rank-1 drop on fresh episodes, its interval and Holm p, and how
    many of the k drops are significant; ``-`` for a run that confirmed nothing."""
    conf = r.get("confirm")
    if not conf:
        return "-"
    ci = conf.get("confirmed_drop_ci95")
    p = conf.get("confirmed_p", conf["shapes"][0].get("p_holm") if conf.get("shapes") else None)
    return (f"{_fmt(conf['confirmed_final_drop'], 'pct')}"
            + (f" [{_fmt(ci[0], 'pct')}, {_fmt(ci[1], 'pct')}]" if ci else "")
            + (f" p={p:.2g}" if p is not None else "") + f" ({conf['confirmed']}/{len(conf['shapes'])})")


def csv_text(rows: list[dict]) -> str:
    """The per-run rows as CSV (the :data:`COLUMNS`)."""
    text = io.StringIO(newline="")
    w = csv.DictWriter(text, fieldnames=COLUMNS, extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    return text.getvalue()


# --- Table 3 (blue-teaming) -------------------------------------------------------------------------

TABLE3_KEYS = ("policy", "geometry", "orig", "blue", "nominal_before", "nominal_after", "heldout_before",
               "heldout_after")


def collect_table3(root: Path) -> list[tuple[Path, list[dict]]]:
    """Every ``table3*.json`` under ``root`` (a blue-team folder's ``table3.json`` or the copies
    ``experiments/`` keeps), each with its rows.

    Raises:
        ReportError: a file is not a list of Table 3 rows.
    """
    root = root.parent if root.is_file() else root
    out = []
    for path in sorted(root.rglob("table3*.json")):
        try:
            rows = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ReportError(f"{path}: cannot read it ({exc}); delete or restore the file") from None
        if not isinstance(rows, list) or any(not isinstance(r, dict) or set(TABLE3_KEYS) - set(r) for r in rows):
            raise ReportError(f"{path}: not a Table 3 file (rows with {', '.join(TABLE3_KEYS)}); report on "
                              "folders written by python -m grt.blueteam")
        out.append((path, rows))
    return out


def table3_markdown(path: Path, rows: list[dict], root: Path) -> str:
    """One blue-team table: success rates in %, a continuous score (a drawer's opening) as stored.

    The rows carry no score name; a success rate is told by its values: every per-geometry score times
    ``trials`` is a whole number of episodes.
    """
    binary = all(abs(r[k] * r.get("trials", 0) - round(r[k] * r.get("trials", 0))) < 1e-6
                 for r in rows for k in ("orig", "blue", "nominal_before", "nominal_after"))
    cell = (lambda v: f"{100 * v:.1f}") if binary else (lambda v: f"{v:.3f}")
    unit = "success %" if binary else "mean score, as stored"
    lines = [f"`{_relative(path, root)}` ({rows[0].get('trials', '?')} held-out episodes per geometry, "
             f"{unit}):", "",
             "| policy | fine-tune | geometry | Orig. | Blue. | Nominal before | Nominal after | Held-out before "
             "| Held-out after |", "|" + "---|" * 9]
    for r in rows:
        lines.append(f"| {r['policy']} | {r.get('fine_tune', '-')} | {r['geometry']} | "
                     + " | ".join(cell(r[k]) for k in TABLE3_KEYS[2:]) + " |")
    return "\n".join(lines)


# --- Records: what a folder holds and which commit wrote it -----------------------------------------

def records_markdown(rows: list[dict], root: Path) -> str:
    """Each summary with the commit that wrote it (``git`` of ``summary.json``) and its search settings."""
    lines = ["| summary | commit | dirty | population x iterations x trials | σ | τ (m) | seed |", "|" + "---|" * 7]
    for r in rows:
        git = r.get("git") or {}
        commit = (git.get("commit") or "-")[:9] if isinstance(git, dict) else str(git)[:9]
        dirty = git.get("dirty") if isinstance(git, dict) else None
        size = " x ".join(_fmt(r.get(k)) for k in ("population", "iterations", "trials"))
        lines.append(f"| `{_relative(Path(r['file']), root)}` | {commit} | {'yes' if dirty else 'no' if dirty is False else '-'} "
                     f"| {size} | {_fmt(r.get('sigma'), 'g')} | {_fmt(r.get('tau'), 'g')} | {_fmt(r.get('seed'))} |")
    return "\n".join(lines)


def _relative(path: Path, root: Path) -> str:
    try:
        return str(path.relative_to(root.parent if root.is_file() else root))
    except ValueError:
        return str(path)


def render(root: Path, records: bool = False) -> str:
    """The record of a folder: its run table (:func:`markdown`), its Table 3 tables, and with
    ``records`` the commit of every summary.

    Raises:
        ReportError: no such folder, nothing to report in it, or a file that is not GRT's.
    """
    rows, failed = collect(root)
    tables = collect_table3(root) if root.exists() else []
    if not rows and not failed and not tables:
        raise ReportError(f"no summary.json (or summary_<name>.json, table3*.json) under {root}: is it a finished "
                          "GRT run folder?")
    parts = [markdown(rows, aggregate(rows), failed)] if rows or failed else []
    from grt.report.search import markdown as search_markdown

    if search := search_markdown(rows):  # runs with trial counts: the search benchmark's table (issue 39)
        parts.append("Simulator trials per method (mean [95% interval] over runs):\n\n" + search)
    from grt.report.margins import margins_markdown

    if margins := margins_markdown(rows):  # runs with a shrink or a robustness profile
        parts.append("How much shape change breaks each policy (sizes: the largest surface displacement; "
                     "intervals in brackets):\n\n" + margins)
    parts += [table3_markdown(path, t, root) for path, t in tables]
    if records and rows:
        parts.append(records_markdown(rows, root))
    return "\n\n".join(parts)


# --- README blocks ----------------------------------------------------------------------------------

BLOCK = re.compile(r"(<!-- grt\.report (?P<args>[^>]*?) -->\n)(?P<body>.*?)(<!-- /grt\.report -->)", re.S)


def update_readme(readme: Path) -> bool:
    """Rewrite every ``<!-- grt.report PATH [--records] -->`` block of ``readme`` from its files.

    Returns:
        Whether the file changed (a second call on an unchanged folder returns False).

    Raises:
        ReportError: a block names a folder with nothing to report, or an unknown option.
    """
    text = readme.read_text()

    def block(m: re.Match) -> str:
        args = shlex.split(m.group("args"))
        unknown = [a for a in args[1:] if a != "--records"]
        if not args or unknown:
            raise ReportError(f"{readme}: a grt.report block takes a folder and --records, not "
                              f"{m.group('args')!r}")
        body = render(readme.parent / args[0], records="--records" in args)
        return f"{m.group(1)}{body}\n{m.group(4)}"

    new = BLOCK.sub(block, text)
    if new == text:
        return False
    write_text_atomic(readme, new)
    return True


def update_readmes(root: Path) -> list[Path]:
    """:func:`update_readme` on every ``README.md`` under ``root`` with a block; the ones that changed."""
    if not root.is_dir():
        raise ReportError(f"{root} is not a folder; give the folder whose README.md files to update "
                          "(e.g. experiments)")
    readmes = sorted(p for p in root.rglob("README.md") if BLOCK.search(p.read_text()))
    return [p for p in readmes if update_readme(p)]
