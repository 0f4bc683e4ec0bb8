"""The paper's heuristic keypoint sampler (appendix, lines 819-855), snapped to mesh vertices.

Every step works on the mesh normalized to the centered unit cube (``grt.geometry.mesh.UnitCubeFrame``),
so the separation ``delta`` is in unit-cube units whatever the object's size:

1. ``P`` uniform surface samples; PCA of the centered cloud gives a right-handed frame ``v1, v2, v3``.
2. Symmetry-aware selection: samples ranked by kNN density
   ``rho(x) = (mean_j ||x - x_j(i)||)^-1``; each high-density sample and its reflections
   ``x - 2 (v_j . x) v_j`` about the principal planes (snapped to the nearest sample) are accepted
   when their L1 distance to every selected keypoint exceeds ``delta``, until about ``N / 2``.
3. Axis-aligned completion: cycling over the principal axes, farthest-point sampling of the
   samples' projections on ``v_j`` (among samples still ``delta`` away in L1) fills up to ``N``.
4. Keypoints are snapped to their nearest mesh vertex (unique), then a pruning pass drops any
   keypoint closer than ``delta`` (Euclidean) to an earlier one, so the returned set may hold
   fewer than ``N`` points (the paper's bowl example has 20).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from grt.geometry.mesh import UnitCubeFrame

SYMMETRIC, AXIS = "symmetric", "axis"


@dataclass(frozen=True)
class Keypoints:
    """Candidate keypoints of a mesh.

    Attributes:
        vertices: ``(K,)`` int mesh vertex indices, unique, in selection order (keypoint ``i`` is
            ``vertices[i]``; the panel and the VLM prompt number them ``0..K-1``).
        positions: ``(K, 3)`` vertex positions in unit-cube units (the frame of ``frame``).
        stages: ``(K,)`` str, ``"symmetric"`` or ``"axis"``: which stage proposed each keypoint.
        axes: ``(3, 3)`` principal axes as rows ``v1, v2, v3`` (right-handed).
        frame: the unit-cube frame of the mesh (``positions = frame.to_unit(mesh.vertices[vertices])``).
    """

    vertices: np.ndarray
    positions: np.ndarray
    stages: np.ndarray
    axes: np.ndarray
    frame: UnitCubeFrame

    def __len__(self) -> int:
        return len(self.vertices)


def principal_axes(points: np.ndarray) -> np.ndarray:
    """Principal axes of a point cloud.

    Args:
        points: ``(P, 3)`` points.

    Returns:
        ``(3, 3)`` rows ``v1, v2, v3`` by decreasing variance, with ``v3 = v1 x v2`` (right-handed).
    """
    X = points - points.mean(0)
    _, vecs = np.linalg.eigh(X.T @ X / len(X))
    v1, v2 = vecs[:, 2], vecs[:, 1]
    return np.stack([v1, v2, np.cross(v1, v2)])


def knn_density(points: np.ndarray, k: int = 16) -> np.ndarray:
    """Inverse mean distance to the ``k`` nearest neighbours, ``(P,)`` (1 / unit-cube units)."""
    dist, _ = cKDTree(points).query(points, k=k + 1)
    return 1.0 / np.maximum(dist[:, 1:].mean(1), 1e-12)


def _far_enough(x: np.ndarray, chosen: list[np.ndarray], delta: float) -> bool:
    return all(np.abs(x - c).sum() > delta for c in chosen)


def _symmetric_stage(X: np.ndarray, axes: np.ndarray, quota: int, delta: float, k: int) -> list[int]:
    """Indices into ``X`` (centered samples) of the symmetry-aware stage, at most ``quota``."""
    tree = cKDTree(X)
    chosen: list[int] = []
    points: list[np.ndarray] = []
    for i in np.argsort(-knn_density(X, k), kind="stable"):
        reflections = [X[i] - 2.0 * (v @ X[i]) * v for v in axes]
        _, snapped = tree.query(np.stack(reflections))
        for j in [int(i), *(int(s) for s in snapped)]:
            if len(chosen) < quota and _far_enough(X[j], points, delta):
                chosen.append(j)
                points.append(X[j])
        if len(chosen) >= quota:
            break
    return chosen


def _axis_stage(X: np.ndarray, axes: np.ndarray, chosen: list[int], total: int, delta: float) -> list[int]:
    """Indices into ``X`` of the axis-aligned completion: 1-D farthest-point sampling per axis."""
    proj = X @ axes.T  # (P, 3) coordinates in the principal frame
    l1 = np.full(len(X), np.inf)
    for c in chosen:
        l1 = np.minimum(l1, np.abs(X - X[c]).sum(1))
    added: list[int] = []
    stalled = 0
    axis = 0
    while len(chosen) + len(added) < total and stalled < 3:
        picked = chosen + added
        gap = np.min(np.abs(proj[:, axis, None] - proj[picked, axis][None]), 1) if picked else \
            np.abs(proj[:, axis] - proj[:, axis].mean())
        gap = np.where(l1 > delta, gap, -np.inf)
        j = int(np.argmax(gap))
        if np.isfinite(gap[j]):
            added.append(j)
            l1 = np.minimum(l1, np.abs(X - X[j]).sum(1))
            stalled = 0
        else:
            stalled += 1
        axis = (axis + 1) % 3
    return added


def prune(points: np.ndarray, delta: float) -> np.ndarray:
    """Greedy pruning: keep a point unless it is closer than ``delta`` to a kept earlier one.

    Args:
        points: ``(K, 3)`` points.
        delta: minimum Euclidean separation.

    Returns:
        ``(K',)`` indices of the kept points, in order.
    """
    kept: list[int] = []
    for i, p in enumerate(points):
        if all(np.linalg.norm(p - points[j]) >= delta for j in kept):
            kept.append(i)
    return np.asarray(kept, dtype=np.int64)


def sample_keypoints(mesh: trimesh.Trimesh, num_keypoints: int = 25, delta: float = 0.1,
                     num_samples: int = 20_000, knn: int = 16, seed: int = 0) -> Keypoints:
    """Run the heuristic keypoint sampler on a mesh (see the module docstring).

    Args:
        mesh: the object (any units; not modified).
        num_keypoints: ``N``, the most keypoints returned (paper: 25).
        delta: minimum separation in unit-cube units (paper: 0.1).
        num_samples: ``P`` uniform surface samples (paper: 20,000).
        knn: neighbours of the density estimate.
        seed: seeds the surface sampling.

    Returns:
        :class:`Keypoints` with at most ``num_keypoints`` unique vertices, pairwise ``>= delta``
        apart (Euclidean, unit-cube units).
    """
    if num_keypoints < 1:
        raise ValueError(f"num_keypoints must be >= 1, got {num_keypoints}")
    frame = UnitCubeFrame.fit(np.asarray(mesh.vertices))
    unit = trimesh.Trimesh(frame.to_unit(mesh.vertices), np.asarray(mesh.faces), process=False)
    samples, _ = trimesh.sample.sample_surface(unit, num_samples, seed=seed)
    center = samples.mean(0)
    X = samples - center
    axes = principal_axes(X)
    sym = _symmetric_stage(X, axes, (num_keypoints + 1) // 2, delta, knn)
    comp = _axis_stage(X, axes, sym, num_keypoints, delta)
    stages = np.array([SYMMETRIC] * len(sym) + [AXIS] * len(comp))
    _, vidx = cKDTree(unit.vertices).query(samples[sym + comp])
    _, first = np.unique(vidx, return_index=True)
    first = np.sort(first)  # unique vertices in selection order
    vidx, stages = np.asarray(vidx[first], np.int64), stages[first]
    kept = prune(unit.vertices[vidx], delta)
    vidx, stages = vidx[kept], stages[kept]
    return Keypoints(vertices=vidx, positions=np.asarray(unit.vertices[vidx]), stages=stages,
                     axes=axes, frame=frame)
