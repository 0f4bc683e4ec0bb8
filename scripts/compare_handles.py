"""Point handles vs smooth handles on the same handle displacements (docs/benchmarks.md, "Deformation").

    python scripts/compare_handles.py --out docs/img/handles.png
    python scripts/compare_handles.py --objects mug,tests/data/real/duck.obj:0.05 --sigma 0.06 --seed 3

One row per object: the nominal mesh with its heuristic handles; the paper's point handles
(``method=exact``) on the object as built (``mesh.remesh=off``, what GRT did before issue 12); GRT's
default, smooth handles (``method=smooth``) on the prepared mesh (``mesh.remesh=auto``). The same
``theta`` drives both. Each title gives the largest spike ratio over the handles
(:func:`grt.geometry.quality.spike_ratios`; a smooth bump gives <= 1.3), the change of angular-deficit
entropy ΔH and the candidate's validity (self-intersecting face pairs, folded faces).
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from grt.geometry.complexity import angular_deficit_entropy  # noqa: E402
from grt.geometry.deform import ShapeDeformer  # noqa: E402
from grt.geometry.mesh import load_mesh  # noqa: E402
from grt.geometry.prepare import MeshSettings  # noqa: E402
from grt.geometry.quality import candidate_validity, spike_ratios  # noqa: E402
from grt.report.plots import _draw_mesh  # noqa: E402
from grt.selectors.heuristic import HeuristicSelector  # noqa: E402


def deform(spec: str, scale: float, method: str, remesh: str, sigma: float, seed: int):
    mesh = load_mesh(spec, scale=scale, settings=MeshSettings(remesh=remesh))
    hs = HeuristicSelector(k=8, seed=seed).select(mesh, "")
    theta = sigma * np.random.default_rng(seed).standard_normal((len(hs.handles), 3))
    shape = ShapeDeformer(mesh, hs.handles, hs.anchors, method=method).meshes(theta[None])[0]
    spike = float(np.nanmax(spike_ratios(mesh.vertices, shape.vertices, hs.handles)))
    dh = angular_deficit_entropy(shape) - angular_deficit_entropy(mesh)
    valid = candidate_validity(mesh, shape)
    return mesh, hs, shape, spike, dh, valid


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--objects", default="mug,tests/data/real/duck.obj:0.05",
                    help="comma-separated built-in names or mesh files, each optionally :SCALE (meters per unit)")
    ap.add_argument("--sigma", type=float, default=0.06, help="handle displacement std, unit-cube units")
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--out", default="docs/img/handles.png")
    args = ap.parse_args()
    objects = [(o.rsplit(":", 1)[0], float(o.rsplit(":", 1)[1])) if ":" in o else (o, 1.0)
               for o in args.objects.split(",")]
    fig = plt.figure(figsize=(12, 3.6 * len(objects)), dpi=110)
    for row, (spec, scale) in enumerate(objects):
        panels = []
        for method, remesh, label in (("exact", "off", "point handles (exact), as built"),
                                      ("smooth", "auto", "smooth handles (default), prepared")):
            mesh, hs, shape, spike, dh, valid = deform(spec, scale, method, remesh, args.sigma, args.seed)
            if not panels:
                panels.append((mesh, f"{spec.split('/')[-1]}: nominal + handles", (0.55, 0.7, 0.9),
                               mesh.vertices[hs.handles]))
            state = "valid" if valid["valid"] else (f"INVALID: {valid['self_intersections']} crossing face pairs, "
                                                    f"{valid['inverted_faces']} folded")
            title = f"{label}\nspike ratio {spike:.2f}, ΔH {dh:+.3f}\n{state}"
            print(f"{spec} {method}: {len(mesh.faces)} faces, {title.replace(chr(10), '; ')}")
            panels.append((shape, title, (0.95, 0.6, 0.45), None))
        for col, (mesh, title, color, points) in enumerate(panels, start=1):
            ax = fig.add_subplot(len(objects), 3, 3 * row + col, projection="3d")
            _draw_mesh(ax, mesh, color, points)
            ax.set_title(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
