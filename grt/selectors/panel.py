"""The canonical view panel (paper appendix, lines 857-868): four labelled views of the keypoints.

Ten viewpoints on the viewing hemisphere, ``(azimuth, elevation)_i = (180 i / n,
180 (0.5 - (i + 0.5) / n))`` degrees with ``n = 10``; four diverse ones (farthest-point sampling of
the view directions, starting from the view closest to 30 degrees of elevation) are rendered in
perspective with matplotlib: the mesh as depth-sorted, Lambert-shaded polygons at low opacity, the
keypoints colored by index with a perceptually uniform colormap (viridis) and their numbers drawn
on top, the world axes at the origin in RGB, arranged in a 2x2 grid labelled A-D. Input coordinates
are the unit-cube frame the VLM also receives, so the axes drawn are the JSON's axes.
"""

from __future__ import annotations

import io

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

LABELS = "ABCD"


def hemisphere_views(n: int = 10) -> np.ndarray:
    """The paper's ``n`` viewpoints, ``(n, 2)`` (azimuth, elevation) in degrees."""
    i = np.arange(n)
    return np.stack([180.0 * i / n, 180.0 * (0.5 - (i + 0.5) / n)], axis=1)


def view_direction(azim: float, elev: float) -> np.ndarray:
    """Unit vector from the origin towards the camera (matplotlib's convention), ``(3,)``."""
    a, e = np.radians(azim), np.radians(elev)
    return np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])


def diverse_views(views: np.ndarray, count: int = 4, start_elev: float = 30.0) -> np.ndarray:
    """Pick ``count`` mutually distant views by farthest-point sampling of their directions.

    Args:
        views: ``(n, 2)`` (azimuth, elevation) degrees.
        count: views kept.
        start_elev: the first view is the one with elevation closest to this.

    Returns:
        ``(count,)`` indices into ``views``.
    """
    dirs = np.stack([view_direction(a, e) for a, e in views])
    picked = [int(np.argmin(np.abs(views[:, 1] - start_elev)))]
    dist = np.linalg.norm(dirs - dirs[picked[0]], axis=1)
    while len(picked) < min(count, len(views)):
        j = int(np.argmax(dist))
        picked.append(j)
        dist = np.minimum(dist, np.linalg.norm(dirs - dirs[j], axis=1))
    return np.asarray(picked)


def _shade(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-face RGBA: a light grey Lambert shading, ``(F, 4)``."""
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    light = np.array([0.3, 0.4, 0.87]) / np.linalg.norm([0.3, 0.4, 0.87])
    level = 0.45 + 0.45 * np.abs(normals @ light)
    rgba = np.ones((len(faces), 4))
    rgba[:, :3] = level[:, None] * np.array([0.75, 0.78, 0.85])
    return rgba


def _draw_view(ax, vertices, faces, colors, points, names, highlight, view, alpha, label) -> None:
    ax.computed_zorder = False  # keypoints and numbers stay visible through the translucent mesh
    rgba = _shade(vertices, faces)
    rgba[:, 3] = alpha
    ax.add_collection3d(Poly3DCollection(vertices[faces], facecolors=rgba, edgecolors="none", zorder=1))
    ax.scatter(*points.T, c=colors, s=40, depthshade=False, zorder=3,
               edgecolors=["red" if h else "black" for h in highlight],
               linewidths=[2.0 if h else 0.5 for h in highlight])
    for p, name in zip(points, names, strict=True):
        ax.text(*(p + 0.02), name, fontsize=9, fontweight="bold", zorder=4,
                bbox=dict(boxstyle="round,pad=0.1", fc="white", ec="none", alpha=0.7))
    for axis, color in enumerate(("red", "green", "blue")):
        tip = np.zeros(3)
        tip[axis] = 0.6
        ax.plot(*np.stack([np.zeros(3), tip]).T, color=color, linewidth=2.5, zorder=2)
        ax.text(*(tip * 1.08), "XYZ"[axis], color=color, fontsize=10, fontweight="bold", zorder=4)
    ax.set_proj_type("persp")
    ax.view_init(elev=float(view[1]), azim=float(view[0]))
    for setter in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
        setter(-0.6, 0.6)
    ax.set_box_aspect((1, 1, 1))
    ax.set_axis_off()
    ax.text2D(0.02, 0.95, label, transform=ax.transAxes, fontsize=22, fontweight="bold")


def render_panel(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                 highlight: np.ndarray | None = None, size_px: int = 1024, alpha: float = 0.25,
                 num_views: int = 10) -> bytes:
    """Render the canonical view panel.

    Args:
        vertices: ``(V, 3)`` mesh vertices, unit-cube units (centered, extent 1).
        faces: ``(F, 3)`` triangles.
        points: ``(K, 3)`` keypoints, unit-cube units; keypoint ``i`` is drawn with the number ``i``.
        highlight: ``(K,)`` bool, keypoints drawn with a red outline (e.g. the chosen handles).
        size_px: the panel's width and height in pixels (each view is half of it).
        alpha: mesh opacity.
        num_views: ``n`` hemisphere viewpoints to choose from.

    Returns:
        PNG bytes of a ``size_px x size_px`` RGB image.
    """
    matplotlib.use("Agg", force=False)  # at drawing time, not on import: a user's backend stays until then
    vertices, faces, points = np.asarray(vertices), np.asarray(faces), np.asarray(points).reshape(-1, 3)
    highlight = np.zeros(len(points), bool) if highlight is None else np.asarray(highlight, bool)
    views = hemisphere_views(num_views)[diverse_views(hemisphere_views(num_views))]
    colors = plt.get_cmap("viridis")(np.linspace(0, 1, max(len(points), 2)))[: len(points)]
    names = [str(i) for i in range(len(points))]
    dpi = 100
    fig = plt.figure(figsize=(size_px / dpi, size_px / dpi), dpi=dpi)
    try:
        for q, view in enumerate(views):
            ax = fig.add_subplot(2, 2, q + 1, projection="3d")
            _draw_view(ax, vertices, faces, colors, points, names, highlight, view, alpha, LABELS[q])
        fig.subplots_adjust(left=0, right=1, bottom=0, top=1, wspace=0, hspace=0)
        fig.add_artist(plt.Line2D([0.5, 0.5], [0, 1], color="black", linewidth=1))  # quadrant borders
        fig.add_artist(plt.Line2D([0, 1], [0.5, 0.5], color="black", linewidth=1))
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi, facecolor="white")
    finally:
        plt.close(fig)
    return buf.getvalue()
