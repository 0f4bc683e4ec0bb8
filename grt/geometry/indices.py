"""Vertex indices a user gave for a mesh file, carried over to the mesh GRT prepared from it.

A user indexes the vertices of the file as it is written (``v`` lines of an OBJ, the vertex list of a
PLY/OFF); loading and repair may reorder them (an OBJ's texture seams split and merged again), drop some
(unreferenced vertices) or replace them all (remeshing, closing). Each index is carried to the prepared
mesh's vertex nearest to its file position; a distance beyond the tolerance, or two indices landing on
one vertex, is refused rather than guessed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree


class IndexMapError(ValueError):
    """Indices of a file that cannot be carried to the prepared mesh unambiguously."""


def file_vertices(path: str | Path) -> np.ndarray:
    """``(N, 3)`` vertex positions of a mesh file in the order its indices count them (file units).

    OBJ: the ``v`` lines (trimesh would split vertices at texture seams); other formats: the vertex list
    as stored (one per triangle corner for STL).
    """
    path = Path(path)
    if path.suffix.lower() == ".obj":
        rows = [line.split()[1:4] for line in path.read_text(errors="replace").splitlines() if line.startswith("v ")]
        return np.asarray(rows, np.float64).reshape(-1, 3)
    loaded = trimesh.load(path, force="mesh", process=False)
    return np.asarray(loaded.vertices, np.float64)


@dataclass
class IndexMap:
    """Where a set of file indices went: ``indices`` into the prepared mesh, ``changed`` how many moved,
    ``distance`` the largest distance between a file vertex and its prepared vertex (mesh units)."""

    indices: np.ndarray
    changed: int
    distance: float


def carry_indices(groups: dict[str, np.ndarray], source: np.ndarray, mesh: trimesh.Trimesh,
                  tolerance: float | None = None) -> dict[str, IndexMap]:
    """Carry each named group of file vertex indices to ``mesh`` (same units as ``source``).

    Args:
        groups: e.g. ``{"handles": (H,), "anchors": (A,)}`` indices into ``source``.
        source: ``(N, 3)`` the file's vertices (:func:`file_vertices`).
        mesh: the prepared mesh.
        tolerance: the largest distance allowed (mesh units); default half the median edge length.

    Raises:
        IndexMapError: an index outside the file, a vertex farther than ``tolerance`` from every prepared
            vertex, or two indices that land on one prepared vertex.
    """
    vertices = np.asarray(mesh.vertices, np.float64)
    if tolerance is None:
        tolerance = 0.5 * float(np.median(mesh.edges_unique_length))
    tree = cKDTree(vertices)
    out, owner = {}, {}
    for name, idx in groups.items():
        idx = np.asarray(idx, np.int64)
        bad = idx[(idx < 0) | (idx >= len(source))]
        if bad.size:
            raise IndexMapError(f"{name} {bad[:10].tolist()} out of range: the file has {len(source)} vertices")
        dist, near = tree.query(source[idx])
        far = np.flatnonzero(dist > tolerance)
        if far.size:
            i = far[np.argmax(dist[far])]
            raise IndexMapError(f"{name[:-1]} {idx[i]} (file position {np.round(source[idx[i]], 6).tolist()}) is "
                                f"{dist[i]:.3g} mesh units from every vertex of the prepared mesh (allowed {tolerance:.3g}); "
                                "index the vertices of the prepared mesh instead, or repair the file first")
        for i, j in zip(idx.tolist(), near.tolist(), strict=True):
            if j in owner and owner[j] != (name, i):
                raise IndexMapError(f"{owner[j][0][:-1]} {owner[j][1]} and {name[:-1]} {i} land on the same vertex {j} "
                                    "of the prepared mesh (duplicates merged or a coarser remeshing); give one of them")
            owner[j] = (name, i)
        same = (near == idx) & (dist == 0.0)
        out[name] = IndexMap(near.astype(np.int64), int((~same).sum()), float(dist.max(initial=0.0)))
    return out
