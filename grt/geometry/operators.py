"""Discrete differential operators on triangle meshes (APAP stage 1 / Neural Jacobian Fields).

Conventions, as in APAP's public stage 1:

* ``G`` — per-face gradient, shape ``(3F, V)``. Row ``3f + d`` holds the ``d``-th component of the
  gradient of the hat functions on face ``f``, so ``(G @ x).reshape(F, 3)`` is the (in-plane, constant)
  gradient of the piecewise-linear function ``x`` on each face.
* ``M`` — diagonal mass, shape ``(3F, 3F)``, holding each face's *double* area three times.
* ``L = Gᵀ M G`` — shape ``(V, V)``, the cotangent stiffness matrix (twice the usual cotangent
  Laplacian with area-weighted faces); symmetric positive semi-definite, constants in its kernel.

A Jacobian field ``J`` is stored as ``(3F, 3)``: ``J[3f + d, c]`` is the derivative of output
coordinate ``c`` along direction ``d`` on face ``f`` (the transposed per-face Jacobian), so that
``J0 = G @ V`` is the field of the rest mesh.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangle areas.

    Args:
        vertices: ``(V, 3)`` float positions.
        faces: ``(F, 3)`` int vertex indices.

    Returns:
        ``(F,)`` areas (units of ``vertices`` squared).
    """
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)


def gradient_operator(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Per-face gradient of piecewise-linear vertex functions.

    On face ``(i, j, k)`` with unit normal ``n`` and area ``A`` the gradient of the hat function of
    vertex ``i`` is ``n x (p_k - p_j) / (2A)`` (and cyclically for ``j`` and ``k``).

    Args:
        vertices: ``(V, 3)`` positions.
        faces: ``(F, 3)`` indices; every face must have non-zero area.

    Returns:
        ``G``, sparse ``(3F, V)``.

    Raises:
        ValueError: if a face is degenerate (zero area), where the gradient is undefined.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    p = [vertices[faces[:, k]] for k in range(3)]
    cross = np.cross(p[1] - p[0], p[2] - p[0])
    double_area = np.linalg.norm(cross, axis=1)
    if np.any(double_area <= 0):
        bad = np.flatnonzero(double_area <= 0)
        raise ValueError(f"{bad.size} degenerate (zero-area) faces, e.g. face {bad[0]}: "
                         "remove them first (grt.geometry.mesh.repair_mesh does).")
    n = cross / double_area[:, None]
    n_faces = faces.shape[0]
    rows, cols, vals = [], [], []
    for k in range(3):
        # edge opposite to vertex k, oriented so the gradient points towards vertex k
        e = p[(k + 2) % 3] - p[(k + 1) % 3]
        g = np.cross(n, e) / double_area[:, None]  # (F, 3)
        for d in range(3):
            rows.append(3 * np.arange(n_faces) + d)
            cols.append(faces[:, k])
            vals.append(g[:, d])
    G = sp.csr_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(3 * n_faces, vertices.shape[0]),
    )
    return G


def mass_matrix(vertices: np.ndarray, faces: np.ndarray) -> sp.dia_matrix:
    """Diagonal face mass with double areas, repeated for the three gradient components.

    Returns:
        ``M``, sparse diagonal ``(3F, 3F)``.
    """
    double_area = 2.0 * face_areas(np.asarray(vertices, np.float64), np.asarray(faces))
    return sp.diags(np.repeat(double_area, 3))


def laplacian(G: sp.spmatrix, M: sp.spmatrix) -> sp.csc_matrix:
    """``L = Gᵀ M G``, the (double-area) cotangent stiffness matrix, ``(V, V)``, symmetric PSD."""
    L = (G.T @ M @ G).tocsc()
    # Symmetrize away round-off so Cholesky sees an exactly symmetric matrix.
    return ((L + L.T) * 0.5).tocsc()


def selector_matrix(indices: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """Indicator matrix ``K`` with ``K @ v == v[indices]``; shape ``(len(indices), V)``."""
    indices = np.asarray(indices, dtype=np.int64)
    data = np.ones(indices.size)
    return sp.csr_matrix((data, (np.arange(indices.size), indices)), shape=(indices.size, n_vertices))
