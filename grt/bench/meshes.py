"""``python -m grt.bench meshes [--run DIR] [--objects A,B] [--skip-300k]``: real meshes in, plausible CrashShapes out.

Three measurements (issue 12), each against a baseline measured in the same process:

1. **Inputs.** Every real mesh of ``tests/data/real`` (pybullet_data, zlib) and a few built-ins through
   the input pipeline (``grt.geometry.prepare``): faces in/out, repairs, volume ratio, Hausdorff and
   Chamfer distance (mm), seconds. Then, on each prepared mesh, 8 random candidates at the demo's σ
   with the paper's point handles (``exact``) and with smooth handles (``smooth``): spike ratio,
   ΔH (angular-deficit entropy) and how many candidates self-intersect or fold.
2. **300k faces.** An icosphere of 327,680 faces: load + prepare (decimate, remesh) + factorization +
   basis of the smooth deformer (the issue's ``prepare_s_300k``), against factorization + basis on
   the raw 300k mesh (the baseline: what a run paid before remeshing).
3. **The demo's CrashShapes** (``--run DIR``: a finished ``python -m grt.run`` folder; without it the
   demo is run into a temporary folder, ~2-3 min): max spike ratio over handles and CrashShapes,
   ΔComplexity, Final Drop, self-intersecting CrashShapes.

The last line is JSON with ``spike_ratio_max``, ``delta_complexity``, ``final_drop``,
``self_intersecting``, ``prepare_s_300k`` (and more).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

REAL = Path(__file__).resolve().parents[2] / "tests" / "data" / "real"
# file -> meters per file unit (the pybullet URDF's scale; see tests/data/real/README.md)
REAL_SCALES = {"duck.obj": 0.05, "teddy_vhacd_hulls.obj": 0.1, "mug_open.obj": 1.0, "toy_cylinder.obj": 1.0,
               "shape_sorter.obj": 0.25, "random_000.obj": 0.015, "random_009.obj": 0.015}
BUILTINS = ("mug", "cup", "spray_bottle", "sugar_box")
SIGMA = 0.06  # the demo's budget.sigma


def _row(cells, widths):
    return "  ".join(str(c)[:w].ljust(w) for c, w in zip(cells, widths, strict=True))


def inputs(objects: list[tuple[str, float]]) -> list[dict]:
    """Measurement 1: the pipeline and both deformers on each object."""
    from grt.geometry.complexity import angular_deficit_entropy
    from grt.geometry.deform import ShapeDeformer
    from grt.geometry.mesh import load_mesh, prepare_report
    from grt.geometry.prepare import MeshSettings
    from grt.geometry.quality import candidate_validity, spike_ratios
    from grt.selectors.heuristic import HeuristicSelector

    rows = []
    for spec, scale in objects:
        row = prepare_report(spec, scale=scale)
        rows.append(row)
        if "error" in row:
            continue
        mesh = load_mesh(spec, scale=scale, settings=MeshSettings(remesh="auto"))
        hs = HeuristicSelector(k=8, seed=0).select(mesh, "")
        thetas = np.random.default_rng(0).normal(0.0, SIGMA, (8, len(hs.handles), 3))
        h0 = angular_deficit_entropy(mesh)
        for method in ("exact", "smooth"):
            shapes = ShapeDeformer(mesh, hs.handles, hs.anchors, method=method).meshes(thetas)
            row[f"{method}_spike"] = round(max(float(np.nanmax(spike_ratios(mesh.vertices, s.vertices, hs.handles)))
                                               for s in shapes), 2)
            row[f"{method}_dH"] = round(float(np.median([angular_deficit_entropy(s) - h0 for s in shapes])), 3)
            row[f"{method}_invalid"] = sum(not candidate_validity(mesh, s)["valid"] for s in shapes)
    return rows


def fine_mesh(tmp: Path) -> tuple[Path, float]:
    """Measurement 2: 300k faces prepared, factored and given a basis; against the raw mesh."""
    from grt.geometry.deform import ShapeDeformer
    from grt.geometry.mesh import load_mesh
    from grt.geometry.prepare import MeshSettings
    from grt.selectors.heuristic import HeuristicSelector

    sphere = trimesh.creation.icosphere(subdivisions=7, radius=0.04)
    sphere.apply_translation([0, 0, 0.04])
    path = tmp / "sphere_300k.ply"
    sphere.export(path)
    out = {}
    for label, remesh in (("prepared", "auto"), ("raw", "off")):
        start = time.perf_counter()
        mesh = load_mesh(path, settings=MeshSettings(remesh=remesh))
        loaded = time.perf_counter() - start
        hs = HeuristicSelector(k=8, seed=0, num_samples=5000).select(mesh, "")
        t = time.perf_counter()
        ShapeDeformer(mesh, hs.handles, hs.anchors, method="smooth")
        out[label] = {"faces": len(mesh.faces), "load_prepare_s": round(loaded, 2),
                      "factor_basis_s": round(time.perf_counter() - t, 2),
                      "total_s": round(loaded + time.perf_counter() - t, 2)}
    return out


def demo_crashshapes(run_dir: Path) -> dict:
    """Measurement 3: spike ratios and validity of a run's CrashShapes, and its metrics."""
    from grt.geometry.quality import candidate_validity, spike_ratios
    from grt.selectors.base import HandleSet

    summary = json.loads((run_dir / "summary.json").read_text())
    nominal = trimesh.load(run_dir / "nominal.obj", process=False, force="mesh")
    handles = HandleSet.from_json((run_dir / "handles.json").read_text()).handles
    spikes, bad = [], 0
    for entry in summary["crashshapes"]:
        shape = trimesh.load(run_dir / entry["file"].replace(".stl", ".obj"), process=False, force="mesh")
        spikes.append(float(np.nanmax(spike_ratios(nominal.vertices, shape.vertices, handles))))
        bad += not candidate_validity(nominal, shape)["valid"]
    return {"run": str(run_dir), "deformer": summary.get("deformer", {}).get("method", "exact"),
            "spike_ratio_max": round(max(spikes), 3) if spikes else None, "crashshapes": len(spikes),
            "self_intersecting": bad, "final_drop": summary["final_drop"], "iter_at_50": summary["iter_at_50"],
            "delta_complexity": summary["delta_complexity"], "invalid_candidates": summary.get("invalid_candidates"),
            "wall_s": summary["wall_s"]}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m grt.bench meshes", description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", help="a finished grt.run folder to measure (default: run the demo now)")
    ap.add_argument("--objects", help="comma-separated objects/mesh files (default: tests/data/real + built-ins)")
    ap.add_argument("--skip-300k", action="store_true", help="skip the 300k-face measurement")
    args = ap.parse_args(argv)
    if args.objects:
        objects = [(o, REAL_SCALES.get(Path(o).name, 1.0)) for o in args.objects.split(",")]
    else:  # the repository's test meshes, when this is a checkout (an installed GRT has the built-ins only)
        real = [(str(REAL / name), scale) for name, scale in REAL_SCALES.items()] if REAL.is_dir() else []
        if not real:
            print(f"no {REAL} (an installed GRT): measuring the built-in objects; --objects takes your files")
        objects = real + [(b, 1.0) for b in BUILTINS]

    rows = inputs(objects)
    widths = (22, 7, 7, 6, 6, 6, 6, 6, 6, 6, 6, 6, 6)
    print(_row(("object", "faces", "->", "vol", "H mm", "C mm", "s", "spk ex", "spk sm", "dH ex", "dH sm",
                "bad ex", "bad sm"), widths))
    for r in rows:
        name = Path(r["object"]).stem
        if "error" in r:
            print(f"{name:22s}  refused: {r['error']}")
            continue
        print(_row((name, r["input_faces"], r["prepared_faces"], f"{r['volume_ratio']:.3f}", f"{r['hausdorff_mm']:.2f}",
                    f"{r['chamfer_mm']:.2f}", f"{r['prepare_s']:.2f}", r["exact_spike"], r["smooth_spike"],
                    r["exact_dH"], r["smooth_dH"], r["exact_invalid"], r["smooth_invalid"]), widths))
    result = {"objects": rows}
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_300k:
            fine = fine_mesh(Path(tmp))
            print(f"300k faces: prepared {fine['prepared']} | raw {fine['raw']} | "
                  f"ratio raw/prepared {fine['raw']['total_s'] / max(fine['prepared']['total_s'], 1e-9):.1f}x")
            result["fine_300k"] = fine
            result["prepare_s_300k"] = fine["prepared"]["total_s"]
        run_dir = Path(args.run) if args.run else Path(tmp) / "demo"
        if not args.run:
            subprocess.run([sys.executable, "-m", "grt.run", f"hydra.run.dir={run_dir}"], check=True)
        demo = demo_crashshapes(run_dir)
    print(f"demo CrashShapes ({demo['deformer']}): spike ratio max {demo['spike_ratio_max']}, "
          f"{demo['self_intersecting']} of {demo['crashshapes']} implausible; Final Drop {demo['final_drop']:.1%}, "
          f"ΔComplexity {demo['delta_complexity']:.3f}")
    result.update({k: demo[k] for k in ("spike_ratio_max", "delta_complexity", "final_drop", "self_intersecting")},
                  demo=demo)
    print(json.dumps(result, default=str))
