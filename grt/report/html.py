"""``report.html``: one self-contained page per run folder, and a sweep page linking them.

:func:`write_run_report` reads a run folder (``summary.json``, ``journal.jsonl``, ``confirm-<n>.jsonl``,
``nominal.obj``, ``crashshapes/``, ``handles.json``, ``run_config.yaml``, ``videos/``) and writes
``report.html`` beside them: the headline metrics with their intervals and units, the search (every
candidate's score per iteration and the degradation curve, inline SVG), the nominal object beside each
CrashShape in 3D coloured by displacement (mm) with its handles and anchors, the failure modes of each
CrashShape's trials against the nominal's on the same seeds, each confirmed CrashShape shrunk to its
smallest confirmed scale and the run's robustness profile (:mod:`grt.report.margins`), the videos of replayed trials, the
mesh-preparation record, the resolved config, the machine and the commit.

The page opens from ``file://`` with no network: the meshes (base64 float32), the videos (data URIs), the
stylesheet and GRT's small WebGL viewer (``assets/viewer.js``, once per page) are all inside it. It
reads files only; it never changes the run folder except for writing ``report.html``.

What a run folder may lack is said on the page, never hidden: a run killed mid-way (no ``summary.json``:
the page is built from the journal and marked partial), deleted mesh files (named; the others render),
no videos (why, from ``videos/videos.json``).
"""

from __future__ import annotations

import base64
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from grt.fileio import write_text_atomic
from grt.journal import restore
from grt.metrics import iter_at_50_label
from grt.report import figures
from grt.report.margins import margins_section
from grt.report.modes import esc, modes_section
from grt.report.tables import ReportError, aggregate, collect
from grt.runfolder.record import resume_command
from grt.scores import ScoreSpec

REPORT = "report.html"
VIDEOS = "videos"
VIDEO_INDEX = "videos.json"


def _asset(name: str) -> str:
    return resources.files("grt.report").joinpath("assets", name).read_text(encoding="utf-8")


# --- Reading a run folder ---------------------------------------------------------------------------

@dataclass
class RunFolder:
    """What a run folder holds, read without changing it."""

    path: Path
    summary: dict | None
    records: list[dict]
    config_text: str
    confirm: list[dict] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  # said on the page (partial run, missing files)

    @property
    def partial(self) -> bool:
        return self.summary is None


def read_journal(path: Path) -> tuple[list[dict], str | None]:
    """The records of a journal, tolerating an interrupted last line (reported, not cut: a report changes
    nothing in the run folder)."""
    if not path.is_file():
        return [], None
    records, problem = [], None
    lines = path.read_text(encoding="utf-8", errors="replace").split("\n")
    for n, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except ValueError:
            if n >= len(lines) - 1:
                problem = f"journal.jsonl: its last line is cut (the run was killed while writing it); {n - 1} lines read"
                break
            raise ReportError(f"{path}: line {n} is not JSON; the journal was edited or damaged. Restore it or "
                              "report on another run") from None
        if isinstance(rec, dict) and "iteration" in rec and "score" in rec:
            records.append(restore(rec))  # NaN scores (refused candidates) are written null
    return records, problem


def load_run(path: Path) -> RunFolder:
    """Read a run folder.

    Raises:
        ReportError: not a run folder (no ``run_config.yaml``, ``journal.jsonl`` or ``summary.json``).
    """
    if not path.exists():
        raise ReportError(f"{path} does not exist; give a run folder (outputs/<task>/<object>/...)")
    if not path.is_dir() or not any((path / n).is_file() for n in ("run_config.yaml", "journal.jsonl", "summary.json")):
        raise ReportError(f"{path} is not a GRT run folder (no run_config.yaml, journal.jsonl or summary.json); "
                          "give the folder python -m grt.run wrote (outputs/<task>/<object>/...)")
    from grt.report.tables import read_summary

    summary = read_summary(path / "summary.json") if (path / "summary.json").is_file() else None
    records, problem = read_journal(path / "journal.jsonl")
    problems = [problem] if problem else []
    config = ""
    for name in ("run_config.yaml", ".hydra/config.yaml"):
        if (path / name).is_file():
            config = (path / name).read_text(encoding="utf-8", errors="replace")
            break
    confirm = []
    for cpath in sorted(path.glob("confirm-*.jsonl")):
        confirm += read_journal(cpath)[0]
    run = RunFolder(path, summary, records, config, confirm, problems)
    if run.partial:
        total = _planned_total(config)
        run.problems.insert(0, f"partial run: no summary.json (the run stopped before its end); {len(records)} "
                               f"candidate(s) in the journal{f' of {total} planned' if total else ''}. "
                               f"Finish it with {resume_command(path)}")
    return run


def _planned_total(config_text: str) -> int | None:
    try:
        import yaml

        data = yaml.safe_load(config_text) or {}
        cfg = data.get("config", data)
        budget = cfg["budget"]
        return 1 + int(budget["population"]) * int(budget["iterations"])
    except Exception:
        return None


def _config(run: RunFolder) -> dict:
    try:
        import yaml

        data = yaml.safe_load(run.config_text) or {}
        return data.get("config", data) if isinstance(data, dict) else {}
    except Exception:
        return {}


# --- Numbers ----------------------------------------------------------------------------------------

def _num(v, fmt="{:.3f}") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return fmt.format(v)


def _interval(ci, fmt) -> str:
    if not ci or ci[0] is None:
        return "-"
    return f"[{fmt(ci[0])}, {fmt(ci[1])}]"


def headline(run: RunFolder, score: ScoreSpec) -> list[tuple[str, str, str, str, str]]:
    """Rows (metric, value, 95% interval, unit, what it is) of the headline table: the confirmed drop first
    (what means something), then the search's figures with Final Drop beside its noise floor."""
    s = run.summary or _summary_from_journal(run.records)
    unit = score.unit or "success rate (0-1)"
    f = score.fmt
    pct = lambda v: _num(v if v is None else 100 * v, "{:.1f}")  # noqa: E731
    s0, best = s.get("s0"), s.get("best_score")
    drop_ci = None
    if s0 and s.get("best_ci95"):
        lo, hi = s["best_ci95"]
        drop_ci = [max(0.0, 1 - hi / s0), min(1.0, 1 - lo / s0)]  # a drop is in [0, 1] (0: none worse than S0)
    rows = []
    conf = s.get("confirm")
    if conf:
        p = conf.get("confirmed_p")
        rows.append(("Confirmed drop", pct(conf["confirmed_final_drop"]), _interval(conf.get("confirmed_drop_ci95"), pct),
                     "% of fresh S0", f"rank-1 CrashShape on {conf['trials']} fresh episodes"
                     + (f", Holm p = {p:.3g}" if p is not None else "") + f"; {esc(figures.confirmed_verdict(s))}"))
    elif run.summary is not None:
        rows.append(("Confirmed drop", "-", "n/a", "% of fresh S0", esc(figures.confirmed_cell(s))))
    floor = figures.floor_of(s) if s else None
    rows += [("S0", f(s0), _interval(s.get("s0_ci95"), f), unit, "nominal object's score on the search's episodes"),
             ("best", f(best), _interval(s.get("best_ci95"), f), unit, "score of the rank-1 CrashShape (ranked by the "
              "lower bound of its drop)"),
             ("Final Drop", pct(s.get("final_drop")), _interval(drop_ci, pct), "% of S0",
              "1 - best / S0; interval: the best candidate's 95% interval with S0 fixed")]
    if floor:
        rows.append(("noise floor of Final Drop", pct(floor["mean"]), f"95%: {pct(floor['q95'])}", "% of S0",
                     esc(figures.floor_sentence(s))))
    rows += [("Iter@50%", iter_at_50_label(s.get("iter_at_50"), s.get("reached_50", True)),
              "n/a", "iterations", "first iteration whose best-so-far drop reaches 50% (a point of the search)"),
             ("AUC", _num(s.get("auc")), "n/a", "drop x iterations (max T)", "area under the degradation curve (trapezoid rule)"),
             ("ΔComplexity", _num(s.get("delta_complexity")), "n/a", "entropy (nats)",
              "angular-deficit entropy of the top candidates minus the nominal's")]
    if conf:
        rows.append((f"S0, {conf['trials']} fresh episodes", f(conf["s0"]), _interval(conf.get("s0_ci95"), f), unit,
                     "nominal object re-scored on episodes the search never used"))
        for c in conf["shapes"]:
            rows.append((f"rank {c['rank']} on fresh episodes", f(c["score"]), _interval(c.get("ci95"), f), unit,
                         f"drop {pct(c['drop'])}% {_interval(c.get('drop_ci95'), pct)} of fresh S0, p = "
                         f"{c['p_value']:.3g}, Holm p = {c['p_holm']:.3g} "
                         f"({'confirmed' if c['confirmed'] else 'not confirmed'} at α = {conf['alpha']})"))
    return rows


def _summary_from_journal(records: list[dict]) -> dict:
    """The metrics a partial run's journal gives (no summary.json)."""
    from grt import metrics

    nominal = next((r for r in records if r["iteration"] == 0), None)
    if nominal is None:
        return {}
    its = sorted({r["iteration"] for r in records if r["iteration"] >= 1})
    scores = [[r["score"] for r in records if r["iteration"] == t] for t in its]
    out = {"s0": nominal["score"], "s0_ci95": nominal.get("ci95")}
    explored = [r for r in records if r["iteration"] >= 1 and r["score"] == r["score"]]
    if explored:
        best = min(explored, key=lambda r: (r["score"], r["iteration"], r["candidate"]))
        out.update(best_score=best["score"], best_ci95=best.get("ci95"))
    if scores:
        out.update(metrics.summarize(nominal["score"], scores))
    return out


# --- Inline SVG -------------------------------------------------------------------------------------

def search_svg(records: list[dict], score: ScoreSpec, width: int = 560, height: int = 300) -> str:
    """Every candidate's score per iteration (dots; refused candidates as crosses at the bottom), the
    best-so-far score (line) and S0 (dashed)."""
    valid = [r for r in records if r["score"] == r["score"]]
    if not valid:
        return "<p class='note'>no scored candidate yet</p>"
    iters = max(r["iteration"] for r in records)
    lo = min(0.0, min(r["score"] for r in valid))
    hi = max(r["score"] for r in valid)
    hi = hi if hi > lo else lo + 1
    m = 56
    x = lambda t: m + (width - m - 12) * (t / max(iters, 1))  # noqa: E731
    y = lambda v: height - 30 - (height - 50) * (v - lo) / (hi - lo)  # noqa: E731
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{width}' height='{height}' viewBox='0 0 {width} {height}' class='search'>",
           f"<line x1='{m}' y1='{height - 30}' x2='{width - 12}' y2='{height - 30}' stroke='#888'/>",
           f"<line x1='{m}' y1='20' x2='{m}' y2='{height - 30}' stroke='#888'/>"]
    for v in np.linspace(lo, hi, 5):
        out.append(f"<text x='{m - 4}' y='{y(v) + 4:.1f}' font-size='10' text-anchor='end'>{score.fmt(float(v))}</text>")
    for t in range(iters + 1):
        out.append(f"<text x='{x(t):.1f}' y='{height - 14}' font-size='10' text-anchor='middle'>{t}</text>")
    out.append(f"<text x='{(width + m) / 2}' y='{height - 1}' font-size='11' text-anchor='middle'>iteration</text>")
    out.append(f"<text x='12' y='{height / 2}' font-size='11' text-anchor='middle' "
               f"transform='rotate(-90 12 {height / 2})'>{esc(score.label)}</text>")
    s0 = next((r["score"] for r in records if r["iteration"] == 0), None)
    if s0 is not None and s0 == s0:
        out.append(f"<line x1='{m}' y1='{y(s0):.1f}' x2='{width - 12}' y2='{y(s0):.1f}' stroke='#2e7d32' "
                   "stroke-dasharray='4 3'><title>S0</title></line>")
    best, pts = math.inf, []
    for t in range(iters + 1):
        its = [r for r in records if r["iteration"] == t]
        for r in its:
            jitter = 0.25 * (r["candidate"] / max(len(its) - 1, 1) - 0.5) * (x(1) - x(0)) if iters else 0
            race = r.get("race") or {}
            if race.get("stopped") and race.get("score") == race.get("score"):  # raced out: its partial mean, hollow
                out.append(f"<circle cx='{x(t) + jitter:.1f}' cy='{y(race['score']):.1f}' r='3' fill='none' "
                           f"stroke='#1565c0' stroke-opacity='0.55'><title>it{t}_c{r['candidate']}: stopped by racing "
                           f"after {race['trials']} of {race['of']} trials ({esc(race['stopped'])}), "
                           f"{score.fmt(race['score'], unit=True)} over them</title></circle>")
                continue
            if r["score"] != r["score"]:
                out.append(f"<text x='{x(t) + jitter:.1f}' y='{height - 33}' font-size='9' fill='#999' "
                           f"text-anchor='middle'>×<title>it{t}_c{r['candidate']}: refused (implausible)</title></text>")
                continue
            best = min(best, r["score"])
            out.append(f"<circle cx='{x(t) + jitter:.1f}' cy='{y(r['score']):.1f}' r='3' fill='#1565c0' "
                       f"fill-opacity='0.55'><title>it{t}_c{r['candidate']}: {score.fmt(r['score'], unit=True)}"
                       "</title></circle>")
        if best < math.inf:
            pts.append(f"{x(t):.1f},{y(best):.1f}")
    out.append(f"<polyline points='{' '.join(pts)}' fill='none' stroke='#c62828' stroke-width='2'/>")
    out.append(f"<text x='{width - 14}' y='14' font-size='10' text-anchor='end'>"
               "<tspan fill='#1565c0'>● candidate</tspan>  <tspan fill='#c62828'>— best so far</tspan>  "
               "<tspan fill='#2e7d32'>- - S0</tspan>  <tspan fill='#999'>× refused</tspan></text></svg>")
    return "".join(out)


def curve_svg(curve: list, width: int = 360, height: int = 300) -> str:
    """The degradation curve (drop relative to S0 per iteration, %)."""
    vals = [c for c in curve or [] if c is not None]
    if not vals:
        return "<p class='note'>no degradation curve (S0 is 0 or no iteration finished)</p>"
    m, n = 40, len(curve)
    x = lambda t: m + (width - m - 10) * t / max(n - 1, 1)  # noqa: E731
    y = lambda v: height - 30 - (height - 50) * v  # noqa: E731
    out = [f"<svg xmlns='http://www.w3.org/2000/svg' width='{width}' height='{height}' viewBox='0 0 {width} {height}' class='curve'>",
           f"<line x1='{m}' y1='{height - 30}' x2='{width - 10}' y2='{height - 30}' stroke='#888'/>",
           f"<line x1='{m}' y1='20' x2='{m}' y2='{height - 30}' stroke='#888'/>",
           f"<line x1='{m}' y1='{y(0.5)}' x2='{width - 10}' y2='{y(0.5)}' stroke='#bbb' stroke-dasharray='3 3'/>"]
    for v in (0, 0.25, 0.5, 0.75, 1.0):
        out.append(f"<text x='{m - 4}' y='{y(v) + 4}' font-size='10' text-anchor='end'>{int(100 * v)}%</text>")
    for t in range(n):
        out.append(f"<text x='{x(t):.1f}' y='{height - 14}' font-size='10' text-anchor='middle'>{t}</text>")
    pts = [f"{x(t):.1f},{y(max(0.0, min(1.0, c))):.1f}" for t, c in enumerate(curve) if c is not None]
    out.append(f"<polyline points='{' '.join(pts)}' fill='none' stroke='#c62828' stroke-width='2'/>")
    out.append(f"<text x='{(width + m) / 2}' y='{height - 1}' font-size='11' text-anchor='middle'>iteration</text>")
    out.append(f"<text x='{width - 12}' y='14' font-size='10' text-anchor='end'>drop of the best so far, % of S0</text></svg>")
    return "".join(out)


# --- Meshes -----------------------------------------------------------------------------------------

def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array).tobytes()).decode()


def _read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of an OBJ in its own vertex order (trimesh, no processing)."""
    import trimesh

    mesh = trimesh.load(path, process=False, force="mesh")
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)


# --- The page ---------------------------------------------------------------------------------------

def _section(title: str, body: str, anchor: str) -> str:
    return f"<h2 id='{anchor}'>{esc(title)}</h2>\n{body}\n"


def _shapes_section(run: RunFolder, page: dict) -> str:
    """The nominal object once, then each CrashShape (3D), in a grid as wide as the page (one column on a phone);
    displacement in mm, handles and anchors marked; every view turns together."""
    s = run.summary or {}
    shapes = s.get("crashshapes") or []
    nominal_path = run.path / "nominal.obj"
    missing = []
    if not nominal_path.is_file():
        missing.append("nominal.obj")
    handles_json = run.path / "handles.json"
    handles, anchors = [], []
    if handles_json.is_file():
        try:
            hs = json.loads(handles_json.read_text())
            handles, anchors = [int(v) for v in hs.get("handles", [])], [int(v) for v in hs.get("anchors", [])]
        except (ValueError, AttributeError):
            run.problems.append("handles.json is not readable: handles and anchors are not marked")
    if not shapes:
        why = "the run is partial: its CrashShapes were not written yet" if run.partial else "the run saved no CrashShape"
        return f"<p class='note'>No CrashShape to show: {why}.</p>" + (
            f"<p class='warn'>missing: {', '.join(missing)}</p>" if missing else "")
    if missing:
        run.problems.append("nominal.obj is missing: the CrashShapes are shown without their displacement")
    nominal_v = faces = None
    if nominal_path.is_file():
        nominal_v, faces = _read_obj(nominal_path)
    parts = []
    for shape in shapes:
        obj = run.path / shape["file"].replace(".stl", ".obj")
        stl = run.path / shape["file"]
        if not obj.is_file() and not stl.is_file():
            missing.append(shape["file"])
            continue
        v, f = _read_obj(obj if obj.is_file() else stl)
        parts.append((shape, v, f, stl if stl.is_file() else None))
    out, cards = [], []
    if missing:
        run.problems.append(f"mesh file(s) deleted from the run folder, not shown: {', '.join(missing)}")
        out.append(f"<p class='warn'>missing mesh files (deleted?), not shown: {esc(', '.join(missing))}</p>")
    ref = nominal_v if nominal_v is not None else (parts[0][1] if parts else None)
    if ref is None:
        return "".join(out)
    lo, hi = ref.min(0), ref.max(0)
    center, size = ((lo + hi) / 2).tolist(), float(np.linalg.norm(hi - lo))
    meshes, face_sets = page["meshes"], page["faces"]

    def add_faces(fa: np.ndarray) -> str:
        key = f"f{len(face_sets)}"
        for k, val in face_sets.items():
            if val[1] == fa.shape and np.array_equal(val[2], fa):
                return k
        face_sets[key] = (_b64(fa.astype(np.uint32)), fa.shape, fa)
        return key

    nominal_key = None
    if nominal_v is not None:
        nominal_key = "nominal"
        meshes[nominal_key] = {"positions": _b64(nominal_v.astype(np.float32)), "faces": add_faces(faces),
                               "center": center, "size": size, "handles": handles, "anchors": anchors}
    out.append("<p class='note'>Drag to turn, wheel to zoom (every view turns together). Colour: "
               "displacement from the nominal object (mm), 0 to the shape's largest; "
               "<span style='color:#e00'>●</span> handles, <span style='color:#2659ff'>●</span> anchors.</p>")
    fresh = {(c["iteration"], c["candidate"]): c for c in (s.get("confirm") or {}).get("shapes", [])}
    score = ScoreSpec.from_summary(s)
    for shape, v, f, stl in parts:
        key = f"rank{shape['rank']}"
        entry = {"positions": _b64(v.astype(np.float32)), "faces": add_faces(f), "center": center, "size": size}
        disp_note = ""
        if nominal_v is not None and v.shape == nominal_v.shape:
            disp = np.linalg.norm(v - nominal_v, axis=1) * 1000.0
            entry.update(values=_b64(disp.astype(np.float32)), vmax=float(disp.max()) or 1.0,
                         handles=handles, anchors=anchors)
            disp_note = (f"displacement: max {disp.max():.1f} mm, mean {disp.mean():.2f} mm "
                         f"(handles: mean {disp[handles].mean():.1f} mm)" if handles else
                         f"displacement: max {disp.max():.1f} mm, mean {disp.mean():.2f} mm")
        else:
            disp_note = "displacement unknown (no nominal.obj with the same vertices)"
        if shape.get("volume_change") is not None:  # recorded since issue 33
            disp_note += f"; volume {shape['volume_change']:+.1%} vs nominal"
        if shape.get("max_dihedral_change_deg") is not None:
            disp_note += f", largest crease change {shape['max_dihedral_change_deg']:.0f}°"
        meshes[key] = entry
        c = fresh.get((shape["iteration"], shape["candidate"]))
        fresh_txt = (f"; fresh episodes {score.fmt(c['score'], unit=True)}, Holm p = {c['p_holm']:.3g}"
                     if c else "")
        links = f"<a href='{esc(shape['file'])}'>{esc(Path(shape['file']).name)}</a> (printable STL, m)" if stl else ""
        if shape.get("file_input_units") and (run.path / shape["file_input_units"]).is_file():
            links += (f"; <a href='{esc(shape['file_input_units'])}'>{esc(Path(shape['file_input_units']).name)}</a> "
                      f"(the input's units, {esc(shape.get('input_unit'))})")
        legend = _legend_svg(entry.get("vmax")) if "values" in entry else ""
        cards.append(f"<div class='card'><h3>rank {shape['rank']}: it{shape['iteration']}_c{shape['candidate']} — "
                     f"search score {score.fmt(shape['score'], unit=True)}{esc(fresh_txt)}</h3>"
                     f"<canvas class='grt-mesh' width='340' height='340' data-mesh='{key}' data-group='shapes'>"
                     f"</canvas><div>{links}</div><div class='note'>{esc(disp_note)}</div>{legend}</div>")
    if nominal_key:  # once, first: every view turns together (one group)
        cards.insert(0, "<div class='card'><h3>nominal object</h3><canvas class='grt-mesh' width='340' height='340' "
                        "data-mesh='nominal' data-group='shapes'></canvas><div><a href='nominal.obj'>nominal.obj</a>"
                        "</div></div>")
    out.append(f"<div class='grid'>{''.join(cards)}</div>")
    return "".join(out)


def _legend_svg(vmax: float | None) -> str:
    if not vmax:
        return ""
    stops = "".join(f"<stop offset='{t}' stop-color='{c}'/>" for t, c in
                    ((0, "#440154"), (0.25, "#3a528b"), (0.5, "#20908d"), (0.75, "#5dc962"), (1, "#fde725")))
    return (f"<svg width='340' height='30' viewBox='0 0 340 30'><defs><linearGradient id='lg{int(vmax * 1000)}'>{stops}</linearGradient>"
            f"</defs><rect x='10' y='2' width='320' height='10' fill='url(#lg{int(vmax * 1000)})'/>"
            f"<text x='10' y='26' font-size='10'>0 mm</text><text x='330' y='26' font-size='10' "
            f"text-anchor='end'>{vmax:.1f} mm</text></svg>")


def mode_meanings(run: RunFolder) -> dict[str, str]:
    """What each trial mode of the run's task means (one line each), from the task module's docstring
    (:func:`grt.tasks.base.mode_meanings`): the same text a developer reads there."""
    from grt.tasks.base import mode_meanings as meanings

    task = _config(run).get("task") or {}
    session = task.get("session") if isinstance(task, dict) else None
    return meanings(session.get("_target_") if isinstance(session, dict) else None)


def _videos_section(run: RunFolder) -> str:
    """The replayed trials' videos (``videos/videos.json``, written by :mod:`grt.rerun`), embedded."""
    index = run.path / VIDEOS / VIDEO_INDEX
    if not index.is_file():
        return ("<p class='note'>No videos: this run rendered none (report.videos=0, budget=smoke, or a run "
                "written before videos existed). python -m grt.replay RUN video=out.mp4 renders one trial.</p>")
    try:
        data = json.loads(index.read_text())
    except ValueError:
        return "<p class='warn'>videos/videos.json is not readable: no videos shown.</p>"
    out = []
    meanings = mode_meanings(run)
    if data.get("skipped"):
        out.append(f"<p class='warn'>No videos: {esc(data['skipped'])}</p>")
    for pair in data.get("pairs", []):
        cards = []
        for clip in pair.get("clips", []):
            path = run.path / VIDEOS / clip["file"]
            if not path.is_file():
                cards.append(f"<div class='card'><p class='warn'>{esc(clip['file'])} is missing</p></div>")
                continue
            mime = "video/webm" if path.suffix == ".webm" else "video/mp4"
            src = f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode()}"
            cards.append(f"<div class='card'><video controls muted loop playsinline preload='auto' src='{src}'>"
                         f"</video><div>{esc(clip['label'])}: <b class='{'' if clip['mode'] == 'success' else 'mode-bad'}'>"
                         f"{esc(clip['mode'])}</b> (journal: {esc(clip.get('journal_mode', '-'))})</div>"
                         f"<div class='note'>{esc(meanings.get(clip['mode'], ''))}</div></div>")
        out.append(f"<h3>{esc(pair['title'])}, episode seed {pair['seed']}</h3><div class='row'>{''.join(cards)}</div>")
    if data.get("camera"):
        out.append(f"<p class='note'>{esc(data['camera'])}</p>")
    return "".join(out)


def _kv_table(d: dict) -> str:
    """A record as a table a person reads: nested records as tables in their cell, lists of plain values
    joined, lists of records one per line, numbers as they are; nothing escaped twice (no literal ``\\u00b2``)."""
    rows = [f"<tr><th class='l'>{esc(str(k).replace('_', ' '))}</th><td class='l'>{_kv_value(v)}</td></tr>"
            for k, v in d.items()]
    return f"<table class='kv'>{''.join(rows)}</table>"


def _kv_value(v) -> str:
    if isinstance(v, dict):
        return _kv_table(v) if v else "-"
    if isinstance(v, list):
        if all(not isinstance(x, (dict, list)) for x in v):
            return esc(", ".join(_plain(x) for x in v)) or "-"
        return "".join(f"<div>{_kv_value(x)}</div>" for x in v)
    return esc(_plain(v))


def _plain(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return "-" if v is None else str(v)


def render_run(path: Path) -> str:
    """The HTML of one run folder's report (see the module docstring)."""
    run = load_run(path)
    s = run.summary or {}
    cfg = _config(run)
    task = s.get("task") or (cfg.get("task") or {}).get("name", "?")
    score = ScoreSpec.from_summary(s) if s else ScoreSpec.from_task(cfg.get("task"))
    title = f"GRT red-team: {task} / {s.get('object') or cfg.get('object', '?')} / " \
            f"{s.get('selector', '?')}-{s.get('optimizer', '?')}"
    page = {"meshes": {}, "faces": {}}
    sections = [
        _section("Headline", _headline_html(run, score), "headline"),
        _section("Search", "<div class='row'>" + search_svg(run.records, score)
                 + curve_svg((run.summary or _summary_from_journal(run.records)).get("curve") or []) + "</div>"
                 + "<p class='note'>Left: every candidate's score per iteration (hover a dot for its name). "
                 "Right: the degradation curve.</p>", "search"),
        _section("CrashShapes", _shapes_section(run, page), "crashshapes"),
        _section("How little change breaks it", margins_section(run.path, s), "margins"),
        _section("Failure modes per CrashShape (same episode seeds as the nominal)",
                 modes_section(run.summary, run.records, run.confirm, mode_meanings(run)), "modes"),
        _section("Videos: the nominal object and each CrashShape on the same episode", _videos_section(run), "videos"),
        _section("Mesh preparation", _kv_table(s["mesh_preparation"]) if s.get("mesh_preparation")
                 else "<p class='note'>not recorded (partial run or an older summary)</p>", "mesh"),
        _section("Resolved config", f"<pre>{esc(run.config_text or 'no run_config.yaml')}</pre>", "config"),
        _section("Machine and code", _machine_html(s), "machine"),
    ]
    problems = "".join(f"<p class='warn'>{esc(p)}</p>" for p in run.problems)
    faces_js = json.dumps({k: v[0] for k, v in page["faces"].items()})
    meshes_js = json.dumps(page["meshes"])
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{esc(title)}</title><style>{_asset('report.css')}</style></head><body>"
            f"<h1>{esc(title)}{' (partial)' if run.partial else ''}</h1>"
            f"<p class='note'>{esc(str(path))} · score: {esc(score.label)}</p>{problems}"
            + "".join(sections)
            + f"<script>window.GRT_FACES = {faces_js};\nwindow.GRT_MESHES = {meshes_js};</script>"
            f"<script>{_asset('viewer.js')}</script></body></html>")


def _headline_html(run: RunFolder, score: ScoreSpec) -> str:
    rows = "".join(f"<tr><th class='l'>{esc(a)}</th><td>{esc(b)}</td><td>{esc(c)}</td><td class='l'>{esc(d)}</td>"
                   f"<td class='l note'>{e}</td></tr>" for a, b, c, d, e in headline(run, score))
    s = run.summary or {}
    extra = []
    if figures.swap_line(s):
        check = s["swap_check"]
        bad = check.get("stock") is not None and not check.get("passed")
        extra.append(f"<p class='{'warn' if bad else 'note'}'>{esc(figures.swap_line(s))}</p>")
    if s.get("note"):
        extra.append(f"<p class='warn'>note: {esc(s['note'])}</p>")
    if s:
        refused = ("not checked (deformer.validity=false)" if s.get("validity_checked") is False else
                   f"{s.get('invalid_candidates', '-')} of {s.get('evaluations', 1) - 1} refused as implausible")
        extra.append(f"<p class='note'>{s.get('evaluations', '-')} candidates ({s.get('population')} x "
                     f"{s.get('iterations')} + nominal), {s.get('trials')} trials each, σ = {s.get('sigma')}, "
                     f"τ = {'off' if s.get('tau') is None else str(s.get('tau')) + ' m'}, seed {s.get('seed')}; {refused}; wall {s.get('wall_s')} s.</p>")
    return ("<table><tr><th class='l'>metric</th><th>value</th><th>95% interval</th><th class='l'>unit</th>"
            f"<th class='l'>what it is</th></tr>{rows}</table>" + "".join(extra))


def _machine_html(s: dict) -> str:
    git = s.get("git") or {}
    commit = f"<p>git commit <code>{esc(git.get('commit', '-'))}</code>{' (uncommitted changes)' if git.get('dirty') else ''}</p>"
    return commit + (_kv_table(s["machine"]) if s.get("machine") else "<p class='note'>machine not recorded</p>")


def write_run_report(path: Path) -> Path:
    """Write ``PATH/report.html`` for one run folder; returns its path.

    Raises:
        ReportError: not a run folder.
    """
    text = render_run(path)
    out = path / REPORT
    write_text_atomic(out, text)
    return out


# --- Sweeps -----------------------------------------------------------------------------------------

def render_sweep(root: Path, links: dict[str, str]) -> str:
    """The paper-table view of a folder of runs, each row linking its run's page."""
    rows, failed = collect(root)
    agg = aggregate(rows)
    pct = lambda v: _num(None if v is None else 100 * v, "{:.1f}")  # noqa: E731
    body = []
    for r in rows:
        score = ScoreSpec.from_summary(r)
        rel = links.get(r["run"])
        name = f"<a href='{esc(rel)}'>{esc(Path(r['run']).relative_to(root) if Path(r['run']) != root else '.')}</a>" \
            if rel else esc(r["run"])
        conf = r.get("confirm") or {}
        body.append(f"<tr><td class='l'>{name}</td><td class='l'>{esc(r['task'])}</td><td class='l'>{esc(r['object'])}</td>"
                    f"<td class='l'>{esc(r.get('policy', '-'))}</td><td class='l'>{esc(r['selector'])}-{esc(r['optimizer'])}</td>"
                    f"<td>{esc(r.get('sigma'))}</td><td>{esc(r.get('seed'))}</td>"
                    f"<td>{esc(figures.confirmed_cell(r)) if conf else '-'}</td><td>{score.fmt(r.get('s0'), unit=True)}</td>"
                    f"<td>{score.fmt(r.get('best_score'), unit=True)}</td><td>{esc(figures.floor_cell(r))}</td>"
                    f"<td>{_num(r['delta_complexity'])}</td>"
                    f"<td>{esc(r['iter_at_50'])}</td><td>{_num(r['auc'])}</td></tr>")
    means = "".join(f"<tr><td class='l'>{esc(a['task'])}</td><td class='l'>{esc(a['policy'])}</td>"
                    f"<td class='l'>{esc(a['method'])}</td><td>{esc(a['sigma'])}</td><td>{a['runs']}</td>"
                    f"<td>{pct(a['confirmed_final_drop'])}</td><td>{pct(a['final_drop'])}</td>"
                    f"<td>{pct(a['noise_floor'])}</td><td>{_num(a['delta_complexity'])}</td>"
                    f"<td>{_num(a['iter_at_50'])}</td><td>{_num(a['auc'])}</td></tr>" for a in agg)
    fail = "".join(f"<li>{esc(p)} (see error.txt)</li>" for p in failed)
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>GRT sweep: {esc(root.name)}</title><style>{_asset('report.css')}</style></head><body>"
            f"<h1>GRT sweep: {esc(str(root))}</h1>"
            "<h2>Per method (mean over runs, as the paper's tables)</h2>"
            "<table><tr><th class='l'>task</th><th class='l'>policy</th><th class='l'>method</th><th>σ</th><th>runs</th>"
            "<th>Confirmed drop (%) ↑</th><th>Final Drop (%) ↑</th><th>noise floor (%)</th><th>ΔComplexity ↓</th>"
            f"<th>Iter@50% ↓</th><th>AUC ↑</th></tr>{means}</table><h2>Runs (each links its report)</h2>"
            "<table><tr><th class='l'>run</th><th class='l'>task</th><th class='l'>object</th><th class='l'>policy</th>"
            "<th class='l'>method</th><th>σ</th><th>seed</th><th>Confirmed drop (%) [95%] p (fresh)</th><th>S0</th>"
            "<th>best</th><th>Final Drop (%) (noise floor)</th><th>ΔComplexity</th><th>Iter@50%</th><th>AUC</th></tr>"
            f"{''.join(body)}</table>" + (f"<h2>Failed jobs</h2><ul>{fail}</ul>" if fail else "")
            + "</body></html>")


def write_report(path: Path) -> list[Path]:
    """``report.html`` for a run folder, or for a sweep (each run's page and the sweep's page linking them).

    Raises:
        ReportError: neither a run folder nor a folder holding run folders.
    """
    if not path.exists():
        raise ReportError(f"{path} does not exist; give a run folder or a sweep folder under outputs/")
    if path.is_dir() and any((path / n).is_file() for n in ("run_config.yaml", "journal.jsonl")):
        return [write_run_report(path)]
    rows, failed = collect(path) if path.is_dir() else ([], [])
    if not rows and not failed:
        raise ReportError(f"{path} is not a GRT run or sweep folder (no run_config.yaml, journal.jsonl or "
                          "summary.json under it); give the folder python -m grt.run wrote")
    written, links = [], {}
    for r in rows:
        run_dir = Path(r["run"])
        if (run_dir / "journal.jsonl").is_file():
            written.append(write_run_report(run_dir))
            links[r["run"]] = str((run_dir / REPORT).relative_to(path))
    out = path / REPORT
    write_text_atomic(out, render_sweep(path, links))
    return [*written, out]
