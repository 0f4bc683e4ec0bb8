"""Point-cloud utilities for grasp predictors: voxel downsampling and oriented PCA normals."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def voxel_downsample(points: np.ndarray, viewpoints: np.ndarray, voxel: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Keep the first point of every occupied voxel (deterministic).

    Args:
        points: ``(P, 3)`` points (m).
        viewpoints: ``(P, 3)`` camera position (m) of each point.
        voxel: voxel edge (m); ``<= 0`` returns the inputs.

    Returns:
        ``(Q, 3)`` points and their ``(Q, 3)`` viewpoints, ``Q <= P``.
    """
    if voxel <= 0 or len(points) == 0:
        return points, viewpoints
    first = voxel_representatives(points, voxel)
    return points[first], viewpoints[first]


def voxel_representatives(points: np.ndarray, voxel: float) -> np.ndarray:
    """Sorted indices of the first point in every occupied voxel of edge ``voxel`` (m). points: ``(P, 3)``."""
    keys = np.floor(points / voxel).astype(np.int64)
    keys -= keys.min(axis=0)
    dims = keys.max(axis=0) + 1
    linear = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    _, first = np.unique(linear, return_index=True)
    return np.sort(first)


def estimate_normals(points: np.ndarray, viewpoints: np.ndarray, k: int = 12) -> np.ndarray:
    """Unit normals from PCA of the ``k`` nearest neighbors, oriented towards the viewing camera.

    Args:
        points: ``(P, 3)`` points (m), ``P >= 3``.
        viewpoints: ``(P, 3)`` camera position (m) that saw each point.
        k: neighbors per point (including the point itself).

    Returns:
        ``(P, 3)`` unit normals; each points to the camera side of the surface (outward).
    """
    k = int(min(k, len(points)))
    _, idx = cKDTree(points).query(points, k=k)
    nbrs = points[idx]  # (P, k, 3)
    centered = nbrs - nbrs.mean(axis=1, keepdims=True)
    cov = np.einsum("pki,pkj->pij", centered, centered)
    _, vecs = np.linalg.eigh(cov)  # ascending eigenvalues: column 0 is the normal
    normals = vecs[:, :, 0]
    flip = np.einsum("pi,pi->p", normals, viewpoints - points) < 0
    normals[flip] *= -1.0
    return normals


def oriented_cloud(points: np.ndarray, viewpoints: np.ndarray, voxel: float, k: int = 12
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Downsampled points with normals estimated camera by camera, then merged.

    Each camera's points get their neighbors from that camera only: a thin wall (a cup's rim) is
    then seen as one surface per camera instead of a blend of its inner and outer faces, whose PCA
    normal would be tangent to the wall.

    Args:
        points: ``(P, 3)`` fused points (m).
        viewpoints: ``(P, 3)`` camera position (m) of each point (one row value per camera).
        voxel: voxel edge (m) of the downsampling (per camera and after merging).
        k: neighbors of the PCA normals.

    Returns:
        ``(Q, 3)`` points and ``(Q, 3)`` unit outward normals.
    """
    cams, which = np.unique(viewpoints, axis=0, return_inverse=True)
    merged_p, merged_n = [], []
    for c in range(len(cams)):
        p, v = voxel_downsample(points[which == c], viewpoints[which == c], voxel)
        if len(p) >= 3:
            merged_p.append(p)
            merged_n.append(estimate_normals(p, v, k))
    if not merged_p:
        return np.zeros((0, 3)), np.zeros((0, 3))
    p, n = np.concatenate(merged_p), np.concatenate(merged_n)
    keep = voxel_representatives(p, voxel) if voxel > 0 else np.arange(len(p))
    return p[keep], n[keep]
