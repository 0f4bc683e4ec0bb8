"""Look at both deformation models on one object: nominal, exact, APAP (Adam-300), and where they differ.

    python scripts/compare_deformers.py --object mug --sigma 0.03 --out docs/img/deformers.png

Prints the Chamfer gap (unit-cube units, mean squared, both directions) and the max vertex gap.
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from grt.geometry.chamfer import chamfer_distance  # noqa: E402
from grt.geometry.deform import ShapeDeformer  # noqa: E402
from grt.geometry.mesh import load_mesh  # noqa: E402
from grt.report.plots import _draw_mesh  # noqa: E402
from grt.selectors.heuristic import HeuristicSelector  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--object", default="mug")
    ap.add_argument("--sigma", type=float, default=0.03, help="handle displacement std, unit-cube units")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="docs/img/deformers.png")
    args = ap.parse_args()
    mesh = load_mesh(args.object)
    hs = HeuristicSelector(k=8, seed=args.seed).select(mesh, "")
    theta = args.sigma * np.random.default_rng(args.seed).standard_normal((len(hs.handles), 3))
    exact = ShapeDeformer(mesh, hs.handles, hs.anchors, method="exact").meshes(theta[None])[0]
    apap = ShapeDeformer(mesh, hs.handles, hs.anchors, method="apap").meshes(theta[None])[0]
    scale = max(mesh.extents)
    cd = chamfer_distance(exact.vertices / scale, apap.vertices / scale)
    gap = np.linalg.norm(exact.vertices - apap.vertices, axis=1)
    print(f"{args.object}: Chamfer(exact, apap) = {cd:.2e} unit-cube units^2; max vertex gap "
          f"{1000 * gap.max():.2f} mm; max displacement exact {1000 * np.linalg.norm(exact.vertices - mesh.vertices, axis=1).max():.2f} mm")
    fig = plt.figure(figsize=(13, 3.6), dpi=110)
    for k, (m, title, color) in enumerate([(mesh, "nominal + handles", (0.55, 0.7, 0.9)),
                                           (exact, "exact (default)", (0.95, 0.6, 0.45)),
                                           (apap, "APAP Adam-300", (0.6, 0.85, 0.55))], start=1):
        ax = fig.add_subplot(1, 4, k, projection="3d")
        _draw_mesh(ax, m, color, mesh.vertices[hs.handles] if k == 1 else None)
        ax.set_title(title, fontsize=9)
    ax = fig.add_subplot(1, 4, 4, projection="3d")
    sc = ax.scatter(*exact.vertices.T, c=1000 * gap, s=2, cmap="magma")
    _draw_mesh(ax, trimesh.Trimesh(exact.vertices, exact.faces, process=False), (1, 1, 1))
    ax.collections[-1].set_alpha(0.05)
    fig.colorbar(sc, ax=ax, shrink=0.6, label="|exact - apap| (mm)")
    ax.set_title(f"difference (Chamfer {cd:.1e})", fontsize=9)
    fig.tight_layout()
    fig.savefig(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
