"""Symmetric Chamfer distance between meshes or point sets.

Convention: the mean of **squared** nearest-neighbour distances in each direction, summed over the
two directions (as in PyTorch3D's ``chamfer_distance`` and the evaluation code APAP builds on)::

    CD(A, B) = mean_a min_b ||a − b||² + mean_b min_a ||b − a||²

The paper (lines 585-600) reports values "×1000" for objects normalized to a unit bounding box
without stating the exponent; squared distances are the common convention in that line of work and
the magnitudes fit (a 1-2 % shape change gives ~1e-4-1e-3). The result is in squared units of the
input: pass unit-cube coordinates to compare with the paper. :func:`chamfer_distance` with
``squared=False`` gives the mean unsquared distance instead.
"""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.spatial import cKDTree


def sample_surface(mesh: trimesh.Trimesh, samples: int, seed: int = 0) -> np.ndarray:
    """``(samples, 3)`` area-uniform random surface points (seeded, reproducible)."""
    if len(mesh.faces) == 0:
        raise ValueError("cannot sample the surface of a mesh without faces")
    rng = np.random.default_rng(seed)
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    area = np.asarray(mesh.area_faces)
    idx = rng.choice(len(f), size=samples, p=area / area.sum())
    u, w = rng.random(samples), rng.random(samples)
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    p0, p1, p2 = (v[f[idx, k]] for k in range(3))
    return p0 + u[:, None] * (p1 - p0) + w[:, None] * (p2 - p0)


def _points(x, samples: int, seed: int) -> np.ndarray:
    if isinstance(x, trimesh.Trimesh):
        return sample_surface(x, samples, seed)
    pts = np.asarray(x, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"expected a trimesh.Trimesh or an (N, 3) point array, got shape {pts.shape}")
    return pts


def chamfer_distance(a, b, samples: int = 20000, seed: int = 0, squared: bool = True) -> float:
    """Symmetric Chamfer distance.

    Args:
        a, b: ``trimesh.Trimesh`` (surface-sampled) or ``(N, 3)`` point arrays, same units.
        samples: surface samples per mesh.
        seed: sampling seed; the same seed on both meshes of equal connectivity samples the same
            barycentric points, which lowers the variance of comparisons between deformations.
        squared: mean of squared distances (default, see module docstring) or of distances.

    Returns:
        ``CD(a, b)`` in squared units of the input (or units if ``squared=False``).
    """
    pa, pb = _points(a, samples, seed), _points(b, samples, seed)
    d_ab, _ = cKDTree(pb).query(pa, workers=-1)
    d_ba, _ = cKDTree(pa).query(pb, workers=-1)
    if squared:
        return float(np.mean(d_ab**2) + np.mean(d_ba**2))
    return float(np.mean(d_ab) + np.mean(d_ba))
