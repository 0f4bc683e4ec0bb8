"""Pictures of a run: the degradation curve and the nominal object beside its CrashShapes."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from grt.scores import ScoreSpec  # noqa: E402


def curve_figure(s0: float, iteration_scores: list[list[float]], title: str = "",
                 score: ScoreSpec | None = None) -> plt.Figure:
    """Per-iteration scores (dots), best-so-far (line) and the nominal score (dashed), labelled with
    the task's score (``success rate``, ``mean opening (m)``); the caller closes the figure."""
    score = score or ScoreSpec()
    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    best = [s0]
    for t, scores in enumerate(iteration_scores, start=1):
        ax.scatter([t] * len(scores), scores, s=14, color="tab:gray", alpha=0.6,
                   label="candidates" if t == 1 else None)
        best.append(min([best[-1], *(x for x in scores if x == x)]))  # NaN: unscorable, skipped
    ax.plot(range(len(best)), best, "-o", color="tab:red", label="best so far")
    ax.axhline(s0, ls="--", color="tab:blue", label=f"nominal S0 = {score.fmt(s0, unit=True)}")
    ax.axhline(0.5 * s0, ls=":", color="tab:blue", alpha=0.6, label="50% of S0")
    ax.set_xlabel("iteration")
    ax.set_ylabel(score.label)
    ax.set_title(title or "degradation curve")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def plot_curve(s0: float, iteration_scores: list[list[float]], path: Path, title: str = "",
               score: ScoreSpec | None = None) -> Path:
    """Save :func:`curve_figure` to ``path`` (``score``: the task's; default a success rate)."""
    fig = curve_figure(s0, iteration_scores, title, score)
    fig.savefig(path)
    plt.close(fig)
    return Path(path)


def _draw_mesh(ax, mesh: trimesh.Trimesh, color, highlight: np.ndarray | None = None,
               elev: float = 25.0, azim: float = -60.0) -> None:
    """Lambert-shaded, back-face-culled triangles (matplotlib sorts by depth); handles as red dots."""
    e, a = np.radians(elev), np.radians(azim)
    eye = np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    front = mesh.face_normals @ eye > 0  # faces turned away would be painted over visible ones
    tris = mesh.vertices[mesh.faces[front]]
    light = np.array([0.4, -0.5, 0.8])
    shade = 0.35 + 0.65 * np.clip(mesh.face_normals[front] @ (light / np.linalg.norm(light)), 0, 1)
    facecolors = np.clip(np.asarray(color)[None, :3] * shade[:, None], 0, 1)
    ax.add_collection3d(Poly3DCollection(tris, facecolors=facecolors, edgecolors=facecolors, linewidths=0.3))
    if highlight is not None and len(highlight):
        ax.computed_zorder = False  # handles stay visible, also those on the far side
        ax.scatter(*highlight.T, color="red", edgecolors="black", s=18, depthshade=False, zorder=10)
    lo, hi = mesh.bounds
    c, r = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=elev, azim=azim)
    ax.set_axis_off()


def plot_shapes(nominal: trimesh.Trimesh, shapes: list[tuple[trimesh.Trimesh, str]], path: Path,
                handles: np.ndarray | None = None) -> Path:
    """Nominal mesh (with its handles) beside the CrashShapes, each titled (e.g. with its score)."""
    n = 1 + len(shapes)
    fig = plt.figure(figsize=(3.2 * n, 3.4), dpi=120)
    ax = fig.add_subplot(1, n, 1, projection="3d")
    _draw_mesh(ax, nominal, (0.55, 0.7, 0.9), None if handles is None else nominal.vertices[handles])
    ax.set_title("nominal", fontsize=9)
    for k, (mesh, label) in enumerate(shapes, start=2):
        ax = fig.add_subplot(1, n, k, projection="3d")
        _draw_mesh(ax, mesh, (0.95, 0.6, 0.45))
        ax.set_title(label, fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)


def plot_divergence(episodes: list[dict], path: Path, title: str = "") -> Path:
    """The swapped actor's pose divergence from the stock actor per control step (mm above, deg below), one line
    per replayed episode, its 0.1 mm-nudge floor dotted (``episodes``: the records of
    :func:`grt.tasks.maniskill.fidelity.check`)."""
    fig, axes = plt.subplots(2, 1, figsize=(7, 5), dpi=120, sharex=True)
    colours = plt.cm.tab10(np.arange(len(episodes)) % 10)
    for e, colour in zip(episodes, colours, strict=True):
        s = e["series"]
        for ax, unit in zip(axes, ("mm", "deg"), strict=True):
            ax.plot(s[f"swap_{unit}"], color=colour, lw=1.2, label=f"seed {e['seed']}: swap vs stock")
            ax.plot(s[f"nudge_{unit}"], color=colour, lw=0.8, ls=":", label=f"seed {e['seed']}: stock nudged 0.1 mm")
    for ax, unit, what in zip(axes, ("mm", "deg"), ("distance between origins", "angle between orientations"),
                              strict=True):
        ax.set_ylabel(f"{what} ({unit})", fontsize=8)
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_ylim(bottom=0)
        ax.axhline(1.0, color="gray", lw=0.6, ls="--")
        ax.grid(alpha=0.3)
    axes[1].set_xlabel("control step")
    axes[0].set_title(title or "open-loop replay: swapped actor vs stock actor", fontsize=9)
    axes[0].legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return Path(path)
