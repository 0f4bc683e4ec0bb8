"""The search benchmark's table and plot (issue 39, ``experiments/search``): which search method finds
CrashShapes with the fewest simulator trials.

Reads the same summaries as :mod:`grt.report.tables` (``summary.json`` of runs, or their ``summary_<name>.json``
copies) that carry ``trials_curve`` (runs since racing existed, :func:`grt.racing.search_figures`). A method is
the optimizer with or without racing; per method, over its runs (objects x seeds): simulator trials used,
trials to the first confirmed CrashShape, Final Drop and AUC, each as a mean with its 95% interval (Student's
t over runs), and the degradation curve against trials used (:func:`plot`).
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np

COLUMNS = ("trials_used", "trials_to_first_confirmed", "final_drop", "auc")


def label(r: dict, optimizer: str | None = None, racing: bool | None = None) -> str:
    """``topdm``, ``topdm + SS + racing``, ``topdm + size 1``: the method of a run (a Smoothness-Score budget
    and a size penalty are other searches, not the same method); ``optimizer``/``racing`` replace the run's."""
    racing = r.get("racing") if racing is None else racing
    return (f"{optimizer or r['optimizer']}" + (" + SS" if r.get("tau") is not None else "")
            + (f" + size {r['size_penalty']:g}" if r.get("size_penalty") else "") + (" + racing" if racing else ""))


def _interval(values: list[float], low: float = 0.0, high: float = math.inf) -> tuple[float, float, float]:
    """Mean and its 95% Student-t interval, cut to what the figure can be (``[low, high]``: a Final Drop of
    three runs at 0, 100 and 100% is 66.7 [0.0, 100.0], not [-77, 210]; never narrower than the values seen);
    the mean twice for a single value, NaNs without values."""
    from scipy import stats

    v = np.asarray([x for x in values if x is not None and not (isinstance(x, float) and math.isnan(x))], float)
    if v.size == 0:
        return (math.nan,) * 3
    if v.size == 1:
        return (float(v[0]),) * 3
    half = float(stats.t.ppf(0.975, v.size - 1) * v.std(ddof=1) / math.sqrt(v.size))
    low, high = min(low, float(v.min())), max(high, float(v.max()))
    return float(v.mean()), max(low, float(v.mean() - half)), min(high, float(v.mean() + half))


def groups(rows: list[dict]) -> dict[tuple[str, str, str], list[dict]]:
    """Runs with trial counts per (task, policy, method)."""
    out: dict[tuple[str, str, str], list[dict]] = defaultdict(list)
    for r in rows:
        if r.get("trials_curve") is not None:
            out[(r["task"], r.get("policy") or "-", label(r))].append(r)
    return dict(sorted(out.items()))


def markdown(rows: list[dict]) -> str:
    """Per (task, policy, method): runs, objects, and each column of :data:`COLUMNS` as ``mean [low, high]``;
    trials relative to the method without racing of the same task and policy on the same runs' objects."""
    found = groups(rows)
    if not found:
        return ""
    lines = ["| task | policy | method | runs | trials used | vs TOPDM without racing | trials to 1st confirmed "
             "CrashShape (runs with one) | Final Drop (%) ↑ | AUC ↑ |", "|" + "---|" * 9]
    for (task, policy, method), rs in found.items():
        plain = label(rs[0], optimizer="topdm", racing=False)  # TOPDM without racing, same budget and penalty
        base = found.get((task, policy, plain))
        ratio = "-"
        if base and method != plain:
            paired = {(r["object"], r.get("seed")): r["trials_used"] for r in base}
            pairs = [r["trials_used"] / paired[(r["object"], r.get("seed"))] for r in rs
                     if (r["object"], r.get("seed")) in paired]
            ratio = _cell(_interval(pairs), "{:.2f}") + f" (n={len(pairs)})" if pairs else "-"
        first = [r.get("trials_to_first_confirmed") for r in rs]
        have = [x for x in first if x is not None]
        cells = [_cell(_interval([r["trials_used"] for r in rs]), "{:.0f}"), ratio,
                 _cell(_interval(have), "{:.0f}") + f" ({len(have)}/{len(rs)})",
                 _cell(_interval([r["final_drop"] * 100 for r in rs], high=100.0), "{:.1f}"),
                 _cell(_interval([r["auc"] for r in rs]), "{:.2f}")]
        lines.append(f"| {task} | {policy} | {method} | {len(rs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _cell(ci: tuple[float, float, float], fmt: str) -> str:
    mean, low, high = ci
    if math.isnan(mean):
        return "-"
    return fmt.format(mean) if low == high else f"{fmt.format(mean)} [{fmt.format(low)}, {fmt.format(high)}]"


def plot(rows: list[dict], path: Path) -> Path:
    """The degradation curve ``C(t)`` against the trials used by iteration ``t``, per method (mean over its
    runs, with the 95% interval of the mean drop as a band), one panel per (task, policy)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    found = groups(rows)
    panels = sorted({(t, p) for t, p, _ in found})
    if not panels:
        raise ValueError("no run with trial counts (trials_curve) to plot")
    fig, axes = plt.subplots(1, len(panels), figsize=(6 * len(panels), 4.2), dpi=120, squeeze=False)
    for ax, (task, policy) in zip(axes[0], panels, strict=True):
        for (t, p, method), rs in found.items():
            if (t, p) != (task, policy):
                continue
            length = min(len(r["trials_curve"]) for r in rs)
            x = np.mean([r["trials_curve"][:length] for r in rs], axis=0)
            ys = np.array([[c if c is not None else np.nan for c in r["curve"][:length]] for r in rs], float) * 100
            stats = [_interval(list(col), high=100.0) for col in ys.T]
            mean, low, high = (np.array(v) for v in zip(*stats, strict=True))
            line, = ax.plot(x, mean, "-o", ms=3, label=f"{method} ({len(rs)} runs)")
            ax.fill_between(x, low, high, color=line.get_color(), alpha=0.12)
        ax.set_xlabel("simulator trials used (mean over runs)")
        ax.set_ylabel("degradation C(t) (%)")
        ax.set_title(f"{task} / {policy}: Final Drop against trials")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)
