"""The failure modes of a run's trials in ``report.html``: stacked bars per CrashShape beside the nominal's,
each mode shown explained in one line (the task module's docstring, :func:`grt.tasks.base.mode_meanings`), and
every trial with its episode seed."""

from __future__ import annotations

import html


def esc(value) -> str:
    return html.escape(str(value), quote=True)


# Mode colours of the stacked bars; a task's own modes take the next free colour in order.
_PALETTE = ["#2e7d32", "#c62828", "#ef6c00", "#6a1b9a", "#1565c0", "#00838f", "#ad1457", "#5d4037", "#9e9d24"]
_FIXED = {"success": "#2e7d32", "sim_error": "#757575"}


def modes_svg(rows: list[tuple[str, dict[str, int]]], colours: dict[str, str], width: int = 520) -> str:
    """Stacked horizontal bars: per row (nominal, a CrashShape...) the share of its trials in each mode."""
    h, label = 22, 150
    height = h * len(rows) + 8
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{width}' height='{height}' class='modes'>"]
    for i, (name, counts) in enumerate(rows):
        total = sum(counts.values()) or 1
        yy, xx = 4 + i * h, label
        out.append(f"<text x='{label - 6}' y='{yy + 14}' font-size='11' text-anchor='end'>{esc(name)}</text>")
        for mode, n in counts.items():
            w = (width - label - 8) * n / total
            out.append(f"<rect x='{xx:.1f}' y='{yy}' width='{w:.1f}' height='{h - 6}' fill='{colours[mode]}'>"
                       f"<title>{esc(mode)}: {n} of {total}</title></rect>")
            if w > 24:
                out.append(f"<text x='{xx + w / 2:.1f}' y='{yy + 12}' font-size='10' fill='#fff' "
                           f"text-anchor='middle'>{n}</text>")
            xx += w
    out.append("</svg>")
    return "".join(out)


def mode_colours(modes) -> dict[str, str]:
    out, free = dict(_FIXED), [c for c in _PALETTE if c not in _FIXED.values()]
    for m in sorted(modes):
        if m not in out:
            out[m] = free[len(out) % len(free)] if free else "#999"
    return out


def meanings_html(modes, meanings: dict[str, str], colours: dict[str, str] | None = None) -> str:
    """One line per mode shown: its swatch (with ``colours``), its name and what it means."""
    lines = []
    for m in sorted(modes, key=lambda m: (m != "success", m)):
        swatch = f"<i class='sw' style='background:{colours[m]}'></i>" if colours and m in colours else ""
        what = esc(meanings.get(m, "not described by the task's module"))
        lines.append(f"<li>{swatch}<b class='{'' if m == 'success' else 'mode-bad'}'>{esc(m)}</b>: {what}</li>")
    return f"<ul class='modes-meaning'>{''.join(lines)}</ul>"


def modes_section(summary: dict | None, records: list[dict], confirm: list[dict], meanings: dict[str, str]) -> str:
    """Per CrashShape: its trials' failure modes beside the nominal's, each mode shown explained in one line
    (``meanings``: :func:`grt.tasks.base.mode_meanings`), the seed of each trial.

    Args:
        summary: the run's ``summary.json`` (``None``: a partial run, its lowest candidates so far are shown).
        records: the journal's records; confirm: the ``confirm-*.jsonl`` records.
    """
    s = summary or {}
    nominal = next((r for r in records if r["iteration"] == 0), None)
    if nominal is None:
        return "<p class='note'>The nominal object was not evaluated yet.</p>"
    by_key = {(r["iteration"], r["candidate"]): r for r in records}
    shapes = [(f"rank {c['rank']} (it{c['iteration']}_c{c['candidate']})", by_key.get((c["iteration"], c["candidate"])))
              for c in s.get("crashshapes") or []]
    if not shapes:  # a partial run: its lowest candidates so far
        explored = sorted((r for r in records if r["iteration"] >= 1 and r["score"] == r["score"]),
                          key=lambda r: (r["score"], r["iteration"], r["candidate"]))[:3]
        shapes = [(f"it{r['iteration']}_c{r['candidate']} (lowest so far)", r) for r in explored]
    shapes = [(n, r) for n, r in shapes if r is not None]
    modes = {t.get("mode", "?") for r in [nominal] + [r for _, r in shapes] for t in r.get("trials", [])}
    colours = mode_colours(modes)
    rows = [("nominal", _counts(nominal))] + [(n, _counts(r)) for n, r in shapes]
    out = [modes_svg(rows, colours), meanings_html(modes, meanings, colours)]
    # seeds: the same episodes for every candidate of the search (common random numbers)
    seeds = [t["seed"] for t in nominal.get("trials", [])]
    head = "".join(f"<th>{esc(n)}</th>" for n, _ in shapes)
    body = []
    for i, seed in enumerate(seeds):
        cells = [_mode_cell(nominal, i, meanings)] + [_mode_cell(r, i, meanings) for _, r in shapes]
        body.append(f"<tr><td>{seed}</td>{''.join(cells)}</tr>")
    out.append("<details><summary>every trial with its episode seed (replay one: python -m grt.replay RUN "
               "candidate=it&lt;t&gt;_c&lt;i&gt; seed=&lt;seed&gt;)</summary>"
               f"<table><tr><th>seed</th><th>nominal</th>{head}</tr>{''.join(body)}</table></details>")
    conf = [r for r in confirm if r.get("trials")]
    if conf:
        out.append("<p class='note'>Confirmation on fresh episodes (confirm-*.jsonl): "
                   + "; ".join(("nominal" if r["iteration"] == 0 else f"it{r['iteration']}_c{r['candidate']}") + ": "
                               + ", ".join(f"{m} {n}" for m, n in sorted(_counts(r).items())) for r in conf) + "</p>")
    return "".join(out)


def _counts(rec: dict) -> dict[str, int]:
    counts: dict[str, int] = {}
    for t in rec.get("trials", []):
        counts[t.get("mode", "?")] = counts.get(t.get("mode", "?"), 0) + 1
    return counts or dict(rec.get("outcomes") or {})


def _mode_cell(rec: dict, i: int, meanings: dict[str, str]) -> str:
    trials = rec.get("trials", [])
    if i >= len(trials):
        return "<td>-</td>"
    mode = trials[i].get("mode", "?")
    return (f"<td class='l{'' if mode == 'success' else ' mode-bad'}' title='{esc(meanings.get(mode, ''))}'>"
            f"{esc(mode)}</td>")
