"""report.html's "How little change breaks it" section: the shrink of each confirmed CrashShape and the run's
robustness profile (the latest ``profile/<time>/profile.json`` in the run folder), read from files only."""

from __future__ import annotations

import base64
import json
from pathlib import Path

from grt.profile import PROFILE_JSON, PROFILE_PNG
from grt.report.modes import esc


def latest_profile(run_dir: Path) -> tuple[Path, dict] | None:
    """``(folder, profile.json)`` of the run's latest finished profile, or ``None``."""
    found = sorted((p for p in Path(run_dir).glob(f"profile/*/{PROFILE_JSON}")), key=lambda p: p.parent.name)
    for path in reversed(found):
        try:
            return path.parent, json.loads(path.read_text())
        except (OSError, ValueError):
            continue
    return None


def margins_section(run_dir: Path, summary: dict) -> str:
    """The section's HTML (a note when the run has neither a shrink nor a profile)."""
    parts = []
    shrink = summary.get("shrink")
    if shrink:
        parts.append(shrink_html(shrink, summary))
    found = latest_profile(run_dir)
    if found:
        parts.append(profile_html(*found, run_dir))
    if not parts:
        return ("<p class='note'>No shrink (it needs confirmed CrashShapes: budget.confirm_trials > 0, budget.shrink="
                f"true) and no profile (python -m grt.profile run={esc(str(run_dir))}).</p>")
    return "".join(parts)


def shrink_html(block: dict, summary: dict) -> str:
    """The table of smallest confirmed scales and each shape's alpha -> score curve."""
    files = {(e["iteration"], e["candidate"]): (e.get("smallest") or {}).get("file")
             for e in summary.get("crashshapes") or []}
    head = ("<tr><th>rank</th><th>smallest α</th><th>largest displacement (mm)</th><th>mean (mm)</th>"
            "<th>of the diagonal</th><th>Smoothness Score (mm)</th><th>σ equivalent</th><th>ΔComplexity</th>"
            "<th>volume</th><th>levels / trials</th><th class='l'>file</th></tr>")
    rows = []
    for s in block["shapes"]:
        f = files.get((s["iteration"], s["candidate"]))
        link = f"<a href='{esc(f)}'>{esc(Path(f).name)}</a>" if f else "-"
        rows.append(f"<tr><td>{s['rank']}</td><td>{s['alpha']:.3g}</td><td>{s['largest_mm']:.2f} (full "
                    f"{s['full']['largest_mm']:.1f})</td><td>{s['mean_mm']:.2f}</td><td>{s['largest_frac']:.2%}</td>"
                    f"<td>{s['smoothness_mm']:.2f}</td><td>{s['sigma_equivalent']:.4f}</td>"
                    f"<td>{s['delta_complexity']:.3f}</td><td>{_pct(s.get('volume_change'))}</td>"
                    f"<td>{s['levels_tested']} / {s['trials_used']}</td><td class='l'>{link}</td></tr>")
    curves = "".join(alpha_svg(s) for s in block["shapes"])
    return (f"<h3>Each confirmed CrashShape, shrunk</h3><p class='note'>The smallest scale α of a CrashShape's "
            f"handle displacements whose drop is still confirmed: levels α = {block['ratio']}^k tested in order "
            f"on {block['trials']} fresh episodes (nominal there: {block['s0']:.2f}), each by a {esc(block['test'])} "
            f"at {block['level_alpha']:.3g} (the run's {block['alpha']} over {len(block['shapes'])} shapes), "
            f"stopping at the first not confirmed; {block['trials_used']} trials in all. σ equivalent: the root "
            "mean square of the shrunk handle displacements in unit-cube units (the paper's σ is 0.001).</p>"
            f"<table>{head}{''.join(rows)}</table><div class='row'>{curves}</div>")


def alpha_svg(shape: dict, width: int = 300, height: int = 200) -> str:
    """One shape's alpha -> score curve with 95% intervals (filled dots: drop confirmed)."""
    m = 36
    x = lambda a: m + (width - m - 10) * a  # noqa: E731
    y = lambda v: height - 28 - (height - 44) * max(0.0, min(1.0, v))  # noqa: E731
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{width}' height='{height}'>",
           f"<line x1='{m}' y1='{height - 28}' x2='{width - 10}' y2='{height - 28}' stroke='#888'/>",
           f"<line x1='{m}' y1='16' x2='{m}' y2='{height - 28}' stroke='#888'/>"]
    for v in (0, 0.5, 1):
        out.append(f"<text x='{m - 4}' y='{y(v) + 4}' font-size='10' text-anchor='end'>{v:g}</text>")
    pts = [p for p in shape["curve"] if p["score"] == p["score"]]
    out.append("<polyline fill='none' stroke='#c62828' points='"
               + " ".join(f"{x(p['alpha']):.1f},{y(p['score']):.1f}" for p in pts) + "'/>")
    for p in pts:
        lo, hi = p.get("ci95") or (p["score"], p["score"])
        fill = "#c62828" if p.get("confirmed") else "white"
        out.append(f"<line x1='{x(p['alpha']):.1f}' x2='{x(p['alpha']):.1f}' y1='{y(lo):.1f}' y2='{y(hi):.1f}' "
                   "stroke='#c62828'/>"
                   f"<circle cx='{x(p['alpha']):.1f}' cy='{y(p['score']):.1f}' r='3.5' fill='{fill}' stroke='#c62828'>"
                   f"<title>α {p['alpha']:.3g}: {p['score']:.2f} over {p['trials']} trials</title></circle>")
    out.append(f"<line x1='{x(shape['alpha']):.1f}' x2='{x(shape['alpha']):.1f}' y1='16' y2='{height - 28}' "
               "stroke='#555' stroke-dasharray='3 3'/>")
    out.append(f"<text x='{(width + m) / 2}' y='{height - 8}' font-size='11' text-anchor='middle'>scale α of "
               f"rank {shape['rank']}'s displacements</text></svg>")
    return "".join(out)


def profile_html(folder: Path, profile: dict, run_dir: Path) -> str:
    """The profile's margins and its picture (inline)."""
    m = profile["margins"]
    rnd = ("below the smallest size" if m["random_mm"] is None else
           f"{m['random_mm']:g} mm{' or more' if m.get('random_beyond') else ''} "
           f"({m['random_interval_mm'][0]:g}-{m['random_interval_mm'][1]:g})")
    adv = ("none confirmed" if m["adversarial_mm"] is None else
           f"{m['adversarial_mm']:g} mm ({m['adversarial_interval_mm'][0]:g}-{m['adversarial_interval_mm'][1]:g})")
    png = folder / PROFILE_PNG
    img = (f"<img alt='robustness profile' src='data:image/png;base64,{base64.b64encode(png.read_bytes()).decode()}'>"
           if png.is_file() else f"<p class='warn'>{esc(str(png))} is missing</p>")
    rel = folder.relative_to(run_dir) if folder.is_relative_to(run_dir) else folder
    return (f"<h3>Robustness profile ({esc(profile['policy'])})</h3><table><tr><th class='l'>margin</th>"
            "<th>size (interval)</th><th class='l'>what it is</th></tr>"
            f"<tr><td class='l'>random</td><td>{esc(rnd)}</td><td class='l note'>the largest size up to which random "
            f"plausible shapes keep success within {profile['crash_margin']:.0%} of S0 = {profile['s0']:.2f}</td></tr>"
            f"<tr><td class='l'>adversarial</td><td>{esc(adv)}</td><td class='l note'>the smallest size at which a "
            "CrashShape's direction is confirmed to break the policy</td></tr></table>"
            f"<p class='note'>Size: {esc(profile['size_measure'])}; {profile['trials']} fresh episodes per shape, "
            f"{profile['trials_used']} trials; <a href='{esc(str(rel / PROFILE_JSON))}'>profile.json</a>.</p>{img}")


def _pct(v) -> str:
    return "-" if v is None else f"{v:+.1%}"


# --- Tables (python -m grt.report) ------------------------------------------------------------------

def profile_of(row: dict) -> dict | None:
    """The profile of a summary row (:func:`grt.report.tables.collect`): the latest ``profile/<time>/profile.json``
    of its run folder, or the ``profile_<name>.json`` kept beside a ``summary_<name>.json`` copy."""
    path = Path(row["file"])
    if path.name.startswith("summary_"):
        twin = path.with_name("profile_" + path.name[len("summary_"):])
        return json.loads(twin.read_text()) if twin.is_file() else None
    found = latest_profile(path.parent)
    return found[1] if found else None


def margins_markdown(rows: list[dict]) -> str:
    """Per run with a shrink or a profile: S0, the two margins (mm) with their intervals and the smallest
    confirmed CrashShape (its largest surface displacement, scale α and σ equivalent); ``""`` when none has."""
    lines = []
    for r in rows:
        prof, shrink = profile_of(r), r.get("shrink")
        if not prof and not shrink:
            continue
        lines.append(f"| {r['task']} | {r['object']} | {_policy(r)} | {_s0(r, prof)} | "
                     f"{_random_cell(prof)} | {_adversarial_cell(prof)} | {_smallest_cell(r)} |")
    if not lines:
        return ""
    head = ["| task | object | policy | S0 (profile episodes) | random margin (mm) | adversarial margin (mm) | "
            "smallest confirmed CrashShape: largest displacement (mm), α, σ equivalent |", "|" + "---|" * 7]
    return "\n".join(head + lines)


def _policy(r: dict) -> str:
    """The policy of a row, ``+ size λ`` for a search for the smallest CrashShape (``budget.size_penalty``), so
    that it is told apart from the same policy's plain search."""
    return (r.get("policy") or "-") + (f" (+ size {r['size_penalty']:g})" if r.get("size_penalty") else "")


def _s0(r: dict, prof: dict | None) -> str:
    if not prof:
        return f"{r['s0']:.2f} (search)"
    low, high = prof["s0_ci95"]
    return f"{prof['s0']:.2f} [{low:.2f}, {high:.2f}]"


def _random_cell(prof: dict | None) -> str:
    if not prof:
        return "- (no profile)"
    m = prof["margins"]
    if m["random_mm"] is None:
        return f"< {prof['sizes_mm'][0]:g} [0, {m['random_interval_mm'][1]:g}]"
    more = "≥ " if m.get("random_beyond") else ""
    return f"{more}{m['random_mm']:g} [{m['random_interval_mm'][0]:g}, {m['random_interval_mm'][1]:g}]"


def _adversarial_cell(prof: dict | None) -> str:
    if not prof:
        return "- (no profile)"
    m = prof["margins"]
    if not prof["adversarial"]:
        return "- (no run)"
    if m["adversarial_mm"] is None:
        return f"none confirmed up to {prof['sizes_mm'][-1]:g}"
    return f"{m['adversarial_mm']:g} ({m['adversarial_interval_mm'][0]:g}, {m['adversarial_mm']:g}]"


def _smallest_cell(r: dict) -> str:
    shrink = r.get("shrink")
    if not shrink:
        conf = r.get("confirm")
        return "no shrink" if not conf else ("none confirmed" if not conf.get("confirmed") else "not shrunk")
    best = min(shrink["shapes"], key=lambda s: s["largest_mm"])
    return (f"{best['largest_mm']:.2f} (α {best['alpha']:.3g}, σ {best['sigma_equivalent']:.4f}; rank {best['rank']} "
            f"of {len(shrink['shapes'])})")


def plot_margins(rows: list[dict], path: Path, small: dict | None = None) -> Path:
    """The margins of every run with a profile, on a log mm axis: random (grey) and adversarial (red) with
    their intervals, the smallest confirmed CrashShape (black x); ``small``: ``{object: mm}`` drawn as a band
    (what the paper calls small)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    found = [(r, p) for r in rows for p in [profile_of(r)] if p]
    if not found:
        raise ValueError("no run with a profile to plot")
    fig, ax = plt.subplots(figsize=(8, 0.5 * len(found) + 1.6), dpi=120)
    for y, (r, p) in enumerate(found):
        m = p["margins"]
        if small and r["object"] in small:
            ax.plot([0.01, small[r["object"]]], [y, y], color="tab:green", lw=8, alpha=0.2, solid_capstyle="butt")
        if m["random_mm"] is not None:
            lo, hi = m["random_interval_mm"]
            ax.errorbar([m["random_mm"]], [y - 0.12], xerr=[[m["random_mm"] - max(lo, 1e-3)], [hi - m["random_mm"]]],
                        fmt="s", color="tab:gray", capsize=3)
        if m["adversarial_mm"] is not None:
            lo, hi = m["adversarial_interval_mm"]
            ax.errorbar([hi], [y + 0.12], xerr=[[hi - max(lo, 1e-3)], [0]], fmt="o", color="tab:red", capsize=3)
        if r.get("shrink"):
            ax.plot([min(s["largest_mm"] for s in r["shrink"]["shapes"])], [y], "kx")
    ax.set_yticks(range(len(found)), [f"{r['object']} / {_policy(r)}" for r, _ in found], fontsize=8)
    ax.set_xscale("log")
    ax.set_xlabel("size: largest surface displacement (mm)")
    ax.set_title("margins: random (grey), adversarial (red), smallest shrunk CrashShape (x)"
                 + ("\ngreen: what the paper calls small on that object" if small else ""), fontsize=9)
    ax.grid(alpha=0.3, which="both", axis="x")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)
