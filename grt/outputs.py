"""What a run leaves in its folder: summary.json, crashshapes/, curve.png, shapes.png, git state."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import trimesh
from omegaconf import DictConfig

from grt import metrics
from grt.config import object_name
from grt.scores import ScoreSpec


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


def crash_records(records: list[dict], k: int) -> list[dict]:
    """The ``k`` lowest-scoring explored candidates (iterations >= 1), earliest first among ties."""
    explored = [r for r in records if r["iteration"] >= 1 and r["score"] == r["score"]]  # not NaN
    return sorted(explored, key=lambda r: (r["score"], r["iteration"], r["candidate"]))[:k]


def save_crashshapes(run_dir: Path, best: list[dict], meshes: list[trimesh.Trimesh], evaluator) -> list[dict]:
    """Write each CrashShape in meters (watertight STL + OBJ, and the convex parts it was simulated with)."""
    out = run_dir / "crashshapes"
    out.mkdir(exist_ok=True)
    saved = []
    for rank, (rec, mesh) in enumerate(zip(best, meshes, strict=True), start=1):
        stem = f"rank{rank}_it{rec['iteration']}_c{rec['candidate']}"
        mesh.export(out / f"{stem}.stl")
        mesh.export(out / f"{stem}.obj")
        entry = {"rank": rank, "file": f"crashshapes/{stem}.stl", "score": rec["score"],
                 "iteration": rec["iteration"], "candidate": rec["candidate"],
                 "watertight": bool(mesh.is_watertight), "smoothness_m": rec.get("smoothness_m")}
        parts_dir = out / f"{stem}_parts"
        parts_dir.mkdir(exist_ok=True)
        for j, verts in enumerate(evaluator.collision_parts(mesh)):
            trimesh.convex.convex_hull(verts).export(parts_dir / f"part{j:02d}.obj")
        entry["parts"] = f"crashshapes/{stem}_parts"
        saved.append(entry)
    return saved


def write_outputs(cfg: DictConfig, run_dir: Path, result, deformer, handle_set, evaluator, wall_s: float) -> dict:
    """Compute the paper's metrics from the journal and write every artifact of the run."""
    from grt.report.plots import plot_curve, plot_shapes

    records = result.records
    score = ScoreSpec.from_task(cfg.task)
    nominal = next(r for r in records if r["iteration"] == 0)
    summ = metrics.summarize(result.s0, result.iteration_scores)
    explored = [(r["score"], r["entropy"]) for r in records if r["iteration"] >= 1 and r["entropy"] is not None]
    best = crash_records(records, cfg.budget.top_k)
    summary = {
        "task": cfg.task.name, "object": object_name(cfg.object), "object_spec": str(cfg.object),
        "selector": _choice(cfg, "selector"), "optimizer": _choice(cfg, "optimizer"),
        "policy": _choice(cfg, "policy"), **score.fields(),
        "s0": result.s0, "s0_ci95": nominal.get("ci95"),
        "best_score": best[0]["score"] if best else None, "best_ci95": best[0].get("ci95") if best else None,
        **summ,
        "delta_complexity": metrics.delta_complexity(nominal["entropy"], explored)
        if nominal.get("entropy") is not None else None,
        "nominal_entropy": nominal.get("entropy"),
        "num_handles": int(len(handle_set.handles)), "num_anchors": int(len(handle_set.anchors)),
        "population": cfg.budget.population, "iterations": cfg.budget.iterations,
        "trials": cfg.budget.trials, "sigma": cfg.budget.sigma, "tau": cfg.budget.tau,
        "evaluations": len(records), "evaluated_this_session": result.evaluations,
        "wall_s": round(wall_s, 1), "git": git_state(),
    }
    if not result.s0 > 0:
        summary["note"] = (f"S0 = {score.fmt(result.s0, unit=True)}: the policy already fails on the nominal "
                           "object; relative drops need a positive S0 and are undefined")
    meshes = deformer.meshes(np.asarray([r["theta"] for r in best])) if best else []
    summary["crashshapes"] = save_crashshapes(run_dir, best, meshes, evaluator)
    # The handle/anchor sets travel with the shapes (indices into every CrashShape's vertices).
    (run_dir / "crashshapes" / "handles.json").write_text(handle_set.to_json())
    title = f"{summary['task']} / {summary['object']} / {summary['selector']}-{summary['optimizer']}"
    plot_curve(result.s0, result.iteration_scores, run_dir / "curve.png", title=title, score=score)
    shapes = [(m, f"it {r['iteration']}: {score.title} {score.fmt(r['score'], unit=True)}")
              for r, m in zip(best, meshes, strict=True)]
    plot_shapes(deformer.mesh, shapes, run_dir / "shapes.png", handles=handle_set.handles)
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=2, allow_nan=True))
    return summary


def _choice(cfg: DictConfig, group: str) -> str:
    """The group option of the run (``heuristic``, ``topdm``...); without Hydra (a test calling
    ``run(cfg)``) it is read from the ``_target_`` module, whose name is the option's by convention."""
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized() and group in HydraConfig.get().runtime.choices:
        return str(HydraConfig.get().runtime.choices.get(group))
    return str(cfg[group]["_target_"]).rsplit(".", 2)[-2]


def print_summary(summary: dict, run_dir: Path) -> None:
    """One screen: the paper's metrics and where the CrashShapes and pictures are."""
    from rich.console import Console
    from rich.table import Table

    score = ScoreSpec.from_summary(summary)
    table = Table(title=f"GRT red-team: {summary['task']} / {summary['object']} "
                        f"({summary['selector']} + {summary['optimizer']})",
                  caption=f"S0 and best: {score.label}; Final Drop, Iter@50% and AUC relative to S0")
    for col in ("S0", "best", "Final Drop", "Iter@50%", "AUC", "ΔComplexity", "evals", "wall s"):
        table.add_column(col, justify="right")
    fmt = lambda v, f="{:.3f}": "-" if v is None or (isinstance(v, float) and v != v) else f.format(v)  # noqa: E731
    table.add_row(score.fmt(summary["s0"], unit=True), score.fmt(summary["best_score"], unit=True),
                  fmt(summary["final_drop"], "{:.1%}"),
                  f"{summary['iter_at_50']}{'' if summary['reached_50'] else ' (not reached)'}",
                  fmt(summary["auc"]), fmt(summary["delta_complexity"]), str(summary["evaluations"]),
                  fmt(summary["wall_s"], "{:.0f}"))
    console = Console()
    console.print(table)
    console.print(f"run folder: {run_dir}\n  curve: {run_dir / 'curve.png'}\n  shapes: {run_dir / 'shapes.png'}"
                  f"\n  CrashShapes: {run_dir / 'crashshapes'}")
