"""What a run leaves in its folder: nominal.obj, summary.json, crashshapes/, curve.png, shapes.png, git state.

Every file is written under a temporary name and renamed into place, so a run killed while writing
leaves the previous version or the new one, never half a file. A resumed run rewrites all of them and
removes the CrashShapes of an earlier writing that are no longer among the lowest scores.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from contextlib import suppress
from pathlib import Path

import numpy as np
import trimesh

from grt import metrics
from grt.console import console as wide_console
from grt.fileio import atomic_path, write_text_atomic
from grt.geometry.quality import shape_change
from grt.noise_floor import noise_floor, simulated_candidates
from grt.plan import RunPlan
from grt.racing import search_figures, stopped
from grt.ranking import drop_lower_bound, ranked
from grt.report import figures
from grt.scores import ScoreSpec, is_crash
from grt.shrink import save_smallest


def git_state() -> dict:
    """Commit and dirty flag of the code that produced a run (empty outside a git checkout)."""
    root = Path(__file__).resolve().parent.parent
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                                timeout=10).stdout.strip()
        dirty = bool(subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root,
                                    capture_output=True, text=True, timeout=10).stdout.strip())
    except (OSError, subprocess.SubprocessError):
        return {}
    return {"commit": commit, "dirty": dirty} if commit else {}


def machine_state() -> dict:
    """What a run's numbers may depend on beyond its config and code: CPU, SIMD flags, thread counts and
    the versions of the numerical and simulation libraries (two machines "of the same kind" gave
    different red-team curves; this makes the difference visible in summary.json)."""
    import hashlib
    import importlib.metadata as md
    import os
    import platform

    info: dict = {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()}
    try:
        text = Path("/proc/cpuinfo").read_text()
        model = next((ln.split(":", 1)[1].strip() for ln in text.splitlines() if ln.startswith("model name")), "")
        flags = next((ln.split(":", 1)[1].split() for ln in text.splitlines() if ln.startswith("flags")), [])
        info.update(cpu=model, simd=sorted(f for f in flags if f.startswith(("avx", "fma", "amx", "sse4"))),
                    cpu_flags_sha=hashlib.sha256(" ".join(sorted(flags)).encode()).hexdigest()[:12])
    except OSError:
        info["cpu"] = platform.processor()
    info["threads"] = {k: os.environ.get(k) for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    try:
        import torch

        info["threads"]["torch"] = torch.get_num_threads()
    except ImportError:
        pass
    versions = {}
    for dist in ("numpy", "scipy", "torch", "sapien", "mani_skill", "coacd", "trimesh", "manifold3d"):
        with suppress(md.PackageNotFoundError):
            versions[dist] = md.version(dist)
    info["versions"] = versions
    return info


def save_nominal(run_dir: Path, mesh: trimesh.Trimesh) -> Path:
    """Write ``nominal.obj``: the mesh the run deforms, in meters, with the vertex order and faces of every
    CrashShape (the indices of ``handles.json`` point into it). Plain ``v``/``f`` lines (no normals or
    texture coordinates, which could make a reader split vertices), 15 decimals: read back with
    ``trimesh.load(path, process=False)`` it is the run's mesh to ~1e-15 m (same ``mesh_hash``)."""
    path = Path(run_dir) / "nominal.obj"
    with atomic_path(path) as tmp:
        mesh.export(tmp, file_type="obj", include_normals=False, include_texture=False, include_color=False,
                    digits=15)
    return path


# What save_crashshapes writes per shape: rank<r>_it<t>_c<i>.stl / .obj (meters), the same in the input's units
# (rank<r>_it<t>_c<i>_mm.stl / .obj with object_scale=0.001) and the _parts folder, and the temporary names of
# atomic_path (left behind only by a kill -9 in the middle of a write).
_TEMP = r"\..+\.[0-9a-f]{8}\.tmp(\.\w+)?"
_CRASHSHAPE = re.compile(rf"rank\d+_it\d+_c\d+(_[a-z]+)?(\.stl|\.obj)|rank\d+_it\d+_c\d+_parts|{_TEMP}")
_PART = re.compile(rf"part\d+\.obj|{_TEMP}")
SHAPES_README = "README.txt"
# Named units of object_scale (meters per mesh unit), as file-name suffixes.
UNITS = {"mm": 0.001, "cm": 0.01, "dm": 0.1, "in": 0.0254, "ft": 0.3048}


def input_unit(scale: float) -> str | None:
    """The name of the input's unit (``object_scale`` meters per mesh unit): ``mm`` for 0.001, ``in`` for
    0.0254 ...; ``input`` for a scale with no name; ``None`` for 1 (meters, the files GRT writes anyway)."""
    scale = float(scale)
    if math.isclose(scale, 1.0, rel_tol=1e-9):
        return None
    return next((name for name, m in UNITS.items() if math.isclose(scale, m, rel_tol=1e-9)), "input")


def crash_records(records: list[dict], k: int, s0: float | None = None, margin: float = 0.0) -> list[dict]:
    """The ``k`` best-ranked explored candidates (iterations >= 1) by the lower bound of their drop
    (:func:`grt.ranking.ranked`); with ``s0``, only the CrashShapes among them: those below ``s0`` by ``margin``
    of it (:func:`grt.scores.is_crash`)."""
    explored = [r for r in records if r["iteration"] >= 1 and r["score"] == r["score"]]  # not NaN
    if s0 is not None:
        explored = [r for r in explored if is_crash(r["score"], s0, margin)]
    return ranked(explored)[:k]


def save_crashshapes(run_dir: Path, best: list[dict], meshes: list[trimesh.Trimesh], evaluator,
                     folder: str = "crashshapes", scale: float = 1.0) -> list[dict]:
    """Write each CrashShape in meters (watertight STL + OBJ, and the convex parts it was simulated with), and,
    for an object given in other units (``scale``: ``object_scale``, meters per input unit), also in the
    input's units (``<stem>_mm.stl`` / ``.obj`` for millimetres, :func:`input_unit`): a slicer or CAD tool
    reads those at the input's size. ``README.txt`` in the folder says which file is in which unit.

    CrashShape files in ``folder`` (``crashshapes/``; ``best/`` for the best candidates of a run that found
    no CrashShape) that this call did not write (an earlier writing's ranks) are removed afterwards, so the
    folder always matches ``summary.json``.
    """
    out = run_dir / folder
    out.mkdir(exist_ok=True)
    unit = input_unit(scale)
    saved, written = [], set()
    for rank, (rec, mesh) in enumerate(zip(best, meshes, strict=True), start=1):
        stem = f"rank{rank}_it{rec['iteration']}_c{rec['candidate']}"
        for ext in ("stl", "obj"):
            with atomic_path(out / f"{stem}.{ext}") as tmp:
                mesh.export(tmp, file_type=ext)
        entry = {"rank": rank, "file": f"{folder}/{stem}.stl", "score": rec["score"],
                 "iteration": rec["iteration"], "candidate": rec["candidate"],
                 "watertight": bool(mesh.is_watertight), "smoothness_m": rec.get("smoothness_m")}
        if unit is not None:
            in_units = trimesh.Trimesh(np.asarray(mesh.vertices) / float(scale), mesh.faces, process=False)
            for ext in ("stl", "obj"):
                with atomic_path(out / f"{stem}_{unit}.{ext}") as tmp:
                    in_units.export(tmp, file_type=ext)
                written.add(f"{stem}_{unit}.{ext}")
            entry.update(file_input_units=f"{folder}/{stem}_{unit}.stl", input_unit=unit)
        parts_dir = out / f"{stem}_parts"
        parts_dir.mkdir(exist_ok=True)
        parts = set()
        for j, verts in enumerate(evaluator.collision_parts(mesh)):
            with atomic_path(parts_dir / f"part{j:02d}.obj") as tmp:
                trimesh.convex.convex_hull(verts).export(tmp, file_type="obj")
            parts.add(f"part{j:02d}.obj")
        _remove_except(parts_dir, parts, _PART)
        entry["parts"] = f"{folder}/{stem}_parts"
        saved.append(entry)
        written |= {f"{stem}.stl", f"{stem}.obj", f"{stem}_parts"}
    _remove_except(out, written, _CRASHSHAPE)
    write_text_atomic(out / SHAPES_README, shapes_readme(folder, unit, scale))
    return saved


def shapes_readme(folder: str, unit: str | None, scale: float) -> str:
    """``README.txt`` of a CrashShape folder: the unit of each file."""
    what = "CrashShapes" if folder == "crashshapes" else "best candidates (no CrashShape: none failed)"
    lines = [f"{folder}/: the run's {what}, ranked (rank1 scored lowest).", "",
             "rank<r>_it<t>_c<i>.stl / .obj: in METERS (what GRT simulated; a slicer that assumes millimetres "
             "shows them 1000x too small: scale by 1000 or use the files below).",
             "rank<r>_it<t>_c<i>_parts/: the convex collision parts the simulator used (meters).",
             "rank<r>_it<t>_c<i>_smallest.stl / .obj: the CrashShape shrunk to the smallest scale of its "
             "displacements whose drop is still confirmed (budget.shrink; meters; summary.json: smallest)."]
    if unit is not None:
        named = f"{unit}" if unit != "input" else f"the input's units, 1 unit = {scale:g} m"
        lines.insert(3, f"rank<r>_it<t>_c<i>_{unit}.stl / .obj: the same shapes in the input mesh's units "
                        f"({named}; object_scale={scale:g}): the size your own files have.")
    lines += ["handles.json: the handle and anchor vertex indices (into every file's vertices).", ""]
    return "\n".join(lines)


def _remove_except(folder: Path, keep: set[str], pattern: re.Pattern) -> None:
    """Remove the entries of ``folder`` named like ``pattern`` that are not in ``keep``."""
    for entry in folder.iterdir():
        if entry.name in keep or not pattern.fullmatch(entry.name):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


def write_outputs(plan: RunPlan, result, deformer, handle_set, evaluator, wall_s: float,
                  confirmation: dict | None = None, shrink: dict | None = None,
                  swap_check: dict | None = None) -> dict:
    """Compute the paper's metrics from the journal and write every artifact of the run in ``plan.run_dir``.

    ``confirmation`` (:func:`grt.confirm.confirm`) adds ``confirm`` and ``confirmed_final_drop`` to the
    summary and each CrashShape's fresh-episode score to ``shapes.png``; ``shrink`` (:func:`grt.shrink.shrink`)
    adds ``shrink``, and to each shrunk CrashShape's entry ``smallest`` and its ``<stem>_smallest.stl``;
    ``swap_check`` (:mod:`grt.swapcheck`) is recorded as it is. ``noise_floor`` (:mod:`grt.noise_floor`) is
    computed here.
    """
    from grt.report.plots import plot_curve, plot_shapes

    run_dir, budget, score, margin = plan.run_dir, plan.budget, plan.score, plan.crash_margin
    _remove_except(run_dir, set(), re.compile(_TEMP))  # temporary files of a write a kill interrupted
    records = result.records
    nominal = next(r for r in records if r["iteration"] == 0)
    summ = metrics.summarize(result.s0, result.iteration_scores)
    tau, tau_how = plan.smoothness_cap(deformer.mesh)
    explored = [(r["score"], r["entropy"]) for r in records if r["iteration"] >= 1 and r["entropy"] is not None]
    crashes = crash_records(records, budget.top_k, result.s0, margin)
    best = crashes or crash_records(records, budget.top_k)  # none failed: the best candidates, named so
    summary = {
        "task": plan.task["name"], "object": plan.object_name, "object_spec": plan.object,
        "selector": str(plan.choices.get("selector")), "optimizer": str(plan.choices.get("optimizer")),
        "policy": str(plan.choices.get("policy")), **score.fields(),
        "s0": result.s0, "s0_ci95": nominal.get("ci95"),
        "crash_margin": margin, "crashshape_found": bool(crashes),
        "best_score": best[0]["score"] if best else None, "best_ci95": best[0].get("ci95") if best else None,
        **summ,
        "noise_floor": noise_floor([tr["score"] for tr in nominal["trials"] if tr.get("mode") != "sim_error"],
                                   simulated_candidates(records), budget.trials, summ["final_drop"], seed=budget.seed),
        "delta_complexity": metrics.delta_complexity(nominal["entropy"], explored)
        if nominal.get("entropy") is not None else None,
        "nominal_entropy": nominal.get("entropy"),
        "num_handles": int(len(handle_set.handles)), "num_anchors": int(len(handle_set.anchors)),
        "population": budget.population, "iterations": budget.iterations,
        "trials": budget.trials, "sigma": budget.sigma, "tau": tau,
        "tau_rel": budget.tau_rel if budget.tau is None else None, "tau_how": tau_how,
        "seed": budget.seed, "size_penalty": budget.size_penalty,
        "evaluations": len(records), "evaluated_this_session": result.evaluations,
        # simulator trials behind the journal (racing: a stopped candidate counts the trials it ran), per
        # iteration, and up to the first (confirmed) CrashShape of the top-k
        **search_figures(records, confirmation),
        "wall_s": round(wall_s, 1), "git": git_state(), "machine": machine_state(),
        "workers": getattr(evaluator, "worker_limits", None),  # requested, used (bounded by cores, memory)
        # where the trials ran: backend (pool or ray), address, nodes, trials per node (this session's)
        "evaluator": evaluator.backend_info() if hasattr(evaluator, "backend_info") else None,
        "mesh_preparation": deformer.mesh.metadata.get("grt_prepare"),  # repairs, remesh, fidelity (mm)
        "deformer": deformer_summary(deformer),
        "invalid_candidates": sum(1 for r in records if r["iteration"] >= 1 and r.get("valid") is False),
        "self_intersecting": sum(1 for r in records if r["iteration"] >= 1 and r.get("self_intersections", 0) > 0),
        # deformer.validity=false: nothing was checked, so the counts above are not "none refused"
        "validity_checked": any("valid" in r for r in records if r["iteration"] >= 1),
        "max_volume_change": plan.deformer.max_volume_change if plan.deformer.validity else None,
    }
    raced = [r for r in records if r["iteration"] >= 1 and r.get("race")]
    cannot_race = budget.racing and not raced and not getattr(evaluator, "races", False)
    if budget.racing and not cannot_race:  # what racing saved; the metrics above count full-trial candidates
        summary["racing"] = {  # only
            "rounds": budget.race_rounds, "alpha": budget.race_alpha, "top_k": budget.top_k,
            "stopped": sum(stopped(r) for r in raced), "full": sum(not stopped(r) for r in raced),
            "trials_all": len(next(r for r in records if r["iteration"] == 0)["trials"]) * (1 + len(raced)),
            "why": {why: sum(r["race"]["stopped"] == why for r in raced) for why in
                    sorted({r["race"]["stopped"] for r in raced if stopped(r)})}}
    if confirmation is not None:
        summary["confirm"] = confirmation
        summary["confirmed_final_drop"] = confirmation["confirmed_final_drop"]
    if swap_check is not None:
        summary["swap_check"] = swap_check
    notes = []
    if cannot_race:  # RedTeamLoop said so in the log; the record says it too, and nothing counts as raced
        notes.append(f"budget.racing=true: {type(evaluator).__name__} runs every trial of a candidate, so "
                     "nothing was raced")
    if not result.s0 > 0:
        notes.append(f"S0 = {score.fmt(result.s0, unit=True)}: the policy already fails on the nominal "
                     "object; relative drops need a positive S0 and are undefined")
    tried = sum(1 for r in records if r["iteration"] >= 1)
    if tried and summary["invalid_candidates"] == tried:
        notes.append(implausible_note(tried, len(handle_set.handles), budget.sigma))
    if not crashes:
        notes.append(no_crashshape_note(margin, len(best)))
    if notes:
        summary["note"] = "; ".join(notes)
    meshes = deformer.meshes(np.asarray([r["theta"] for r in best])) if best else []
    folder, other = ("crashshapes", "best") if crashes else ("best", "crashshapes")
    entries = save_crashshapes(run_dir, best, meshes, evaluator, folder=folder,
                               scale=plan.object_scale)
    for entry, mesh, rec in zip(entries, meshes, best, strict=True):  # how far each is from the nominal
        entry.update(shape_change(deformer.mesh, mesh), drop_lower_bound=drop_lower_bound(rec, result.s0))
    summary["crashshapes"] = entries if crashes else []
    if shrink is not None and crashes:
        save_smallest(run_dir, entries, shrink, deformer, {(r["iteration"], r["candidate"]): r["theta"] for r in best})
        summary["shrink"] = shrink
    if not crashes:
        summary["best_candidates"] = entries
    if (run_dir / other).is_dir():  # a resumed run whose verdict changed: its other folder's shapes go
        _remove_except(run_dir / other, set(), _CRASHSHAPE)
    # The handle/anchor sets travel with the shapes (indices into every CrashShape's vertices).
    write_text_atomic(run_dir / folder / "handles.json", handle_set.to_json())
    title = f"{summary['task']} / {summary['object']} / {summary['selector']}-{summary['optimizer']}"
    with atomic_path(run_dir / "curve.png") as tmp:
        plot_curve(result.s0, result.iteration_scores, tmp, title=title, score=score)
    fresh = {(c["iteration"], c["candidate"]): c for c in (confirmation or {}).get("shapes", [])}
    shapes = [(m, f"{'' if crashes else 'best (no CrashShape) '}it {r['iteration']}: {score.title} "
                  f"{score.fmt(r['score'], unit=True)}" + _fresh_label(fresh.get((r["iteration"], r["candidate"])), score))
              for r, m in zip(best, meshes, strict=True)]
    with atomic_path(run_dir / "shapes.png") as tmp:
        plot_shapes(deformer.mesh, shapes, tmp, handles=handle_set.handles)
    write_text_atomic(run_dir / "summary.json", json.dumps(summary, indent=2, allow_nan=True))
    return summary


def no_crashshape_note(margin: float, kept: int) -> str:
    """What a run that found no failure says, and where its best candidates are."""
    return (f"no CrashShape found: no candidate scored below S0 by task.crash_margin={margin:g} ({margin:.0%} of "
            f"S0)" + (f"; the {kept} best candidates are kept in best/ (not failures)" if kept else ""))


def implausible_note(candidates: int, handles: int, sigma: float) -> str:
    """Why a run found nothing when the validity checks refused every candidate, and what to change."""
    return (f"all {candidates} candidates were implausible (self-intersecting or folded) and none was simulated, "
            f"so the search found nothing: {handles} handles at budget.sigma={sigma:g} fold the object; "
            "lower budget.sigma, cap the mean displacement (budget.tau) or use fewer handles (selector=heuristic); "
            f"python -m grt.select with the run's object and selector and 'probe.sigmas=[{sigma / 4:g},{sigma / 2:g}]' "
            "counts, without simulating, the candidates each sigma folds")


def _fresh_label(confirmed: dict | None, score: ScoreSpec) -> str:
    """`` / fresh 0.41*``: a CrashShape's score on the confirmation episodes (``*``: a confirmed drop)."""
    if confirmed is None:
        return ""
    return f" / fresh {score.fmt(confirmed['score'])}{'*' if confirmed['confirmed'] else ''}"


def deformer_summary(deformer) -> dict:
    """The deformation model of a run, as ``summary.json`` records it."""
    core = deformer.core
    out = {"method": core.method, "lam": core.lam}
    if core.method == "smooth":
        out.update(radius=core.radius, radius_m=core.region_radius * deformer.meters_per_unit,
                   released_anchors=core.released_anchors.tolist())
    return out


def print_summary(summary: dict, run_dir: Path) -> None:
    """One screen: the paper's metrics and where the CrashShapes and pictures are."""
    from rich.table import Table

    score = ScoreSpec.from_summary(summary)
    table = Table(title=f"GRT red-team: {summary['task']} / {summary['object']} "
                        f"({summary['selector']} + {summary['optimizer']})",
                  caption=f"S0 and best: {score.label}; drops relative to S0. Confirmed drop: rank-1 on fresh "
                          "episodes [95% interval], Holm p. Final Drop (noise floor: mean, 95th percentile)")
    for col in ("Confirmed drop", "S0", "best", "Final Drop", "Iter@50%", "AUC", "ΔComplexity", "evals", "wall s"):
        table.add_column(col, justify="right")
    fmt = lambda v, f="{:.3f}": "-" if v is None or (isinstance(v, float) and v != v) else f.format(v)  # noqa: E731
    table.add_row(figures.confirmed_cell(summary, "%"), score.fmt(summary["s0"], unit=True),
                  score.fmt(summary["best_score"], unit=True), figures.floor_cell(summary, "%"),
                  metrics.iter_at_50_label(summary["iter_at_50"], summary["reached_50"]),
                  fmt(summary["auc"]), fmt(summary["delta_complexity"]), str(summary["evaluations"]),
                  fmt(summary["wall_s"], "{:.0f}"))
    console = wide_console()  # in a log: as wide as the table and the paths (grt.console)
    console.print(table)
    invalid, tried = summary.get("invalid_candidates", 0), summary["evaluations"] - 1
    if tried and summary.get("validity_checked") is False:
        console.print("plausibility not checked (deformer.validity=false): folded candidates were simulated too")
    elif invalid:
        why = "self-intersecting, folded" + (f" or volume changed > {summary['max_volume_change']:.0%}"
                                             if summary.get("max_volume_change") is not None else "")
        console.print(f"implausible: {invalid} of {tried} candidates ({why}), not simulated")
    if summary.get("note"):
        console.print(f"note: {summary['note']}", style="yellow", markup=False)
    for line in (figures.swap_line(summary), figures.floor_sentence(summary)):
        if line:
            console.print(line, markup=False)
    conf = summary.get("confirm")
    if conf:
        lines = [f"rank {c['rank']}: {score.fmt(c['score'], unit=True)} (search {score.fmt(c['search_score'])}), "
                 f"drop {fmt(c['drop'], '{:.1%}')}, p = {c['p_holm']:.3g} (Holm)"
                 f"{' confirmed' if c['confirmed'] else ' not confirmed'}{_unsettled_words(c, conf)}"
                 for c in conf["shapes"]]
        console.print(f"confirmed on {conf['trials']} fresh episodes: S0 {score.fmt(conf['s0'], unit=True)}; "
                      f"{figures.confirmed_verdict(summary)}\n  " + "\n  ".join(lines), markup=False)
    shapes = summary.get("crashshapes") or summary.get("best_candidates") or []
    if shapes and "volume_change" in shapes[0]:
        console.print("shape change vs nominal: " + "; ".join(
            f"rank {e['rank']}: volume {fmt(e['volume_change'], '{:+.1%}')}, max dihedral change "
            f"{fmt(e['max_dihedral_change_deg'], '{:.0f}')}°" for e in shapes))
    found = summary.get("crashshape_found", True)
    unit = next((e["input_unit"] for e in shapes if e.get("input_unit")), None)
    units = f" (meters; in the input's units too: rank*_{unit}.stl, see README.txt there)" if unit else " (meters)"
    where = f"CrashShapes: {run_dir / 'crashshapes'}{units}" if found else \
        f"no CrashShape found; best candidates (not failures): {run_dir / 'best'}{units}"
    console.print(f"run folder: {run_dir}\n  curve: {run_dir / 'curve.png'}\n  shapes: {run_dir / 'shapes.png'}"
                  f"\n  {where}")


def _unsettled_words(shape: dict, conf: dict) -> str:
    """``; in n/m episodes the object was still moving or had fallen over ... (nominal k/m) ...`` for a
    confirmed CrashShape whose object was so in most of its confirmation episodes (:func:`grt.confirm.unsettled`);
    ``""`` otherwise."""
    n, m = shape.get("unsettled"), shape.get("stance_trials")
    if not shape.get("confirmed") or not m or n * 2 <= m:
        return ""
    return (f"; in {n}/{m} episodes the object was still moving or had fallen over when the policy looked "
            f"(nominal {conf.get('unsettled', 0)}/{conf.get('stance_trials', m)}): this drop is the shape's "
            "stability more than the policy's")
