"""Sparse symmetric positive-definite solves, factored once and reused.

Measured on the 2-core reference machine by ``python -m grt.bench deform`` (A = LᵀL + λSᵀS of its
10k-face test mesh, 4979 vertices, 300 anchors; 16 right-hand sides):

=============  ==========  ===============
backend        factor (s)  solve, 16 RHS
=============  ==========  ===============
cholespy 2.2   0.07-0.12   3.5-5 ms
scipy splu     0.19-0.21   21-192 ms
=============  ==========  ===============

(ranges over two runs on a shared, loaded machine.)

cholespy (a supernodal Cholesky with CPU and GPU builds, wheels on PyPI) is the default; SciPy's
SuperLU is the fallback when cholespy is missing (same results; 6-40x slower solves, which matters
for the exact basis and the APAP mode's solves, not for per-candidate exact deformations). CHOLMOD
(scikit-sparse) needs SuiteSparse headers to build and did not install from PyPI here.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla


class SparseCholesky:
    """Factor an SPD sparse matrix once; ``solve`` any number of right-hand sides.

    Args:
        A: ``(n, n)`` sparse symmetric positive-definite matrix.
        backend: ``"auto"`` (cholespy, else SciPy), ``"cholespy"`` or ``"scipy"``.
    """

    def __init__(self, A: sp.spmatrix, backend: str = "auto"):
        self.n = A.shape[0]
        if backend in ("auto", "cholespy"):
            try:
                from cholespy import CholeskySolverD, MatrixType
            except ImportError:
                if backend == "cholespy":
                    raise
                backend = "scipy"
            else:
                coo = A.tocoo()
                self._impl = CholeskySolverD(self.n, coo.row.astype(np.int32), coo.col.astype(np.int32),
                                             coo.data.astype(np.float64), MatrixType.COO)
                self.backend = "cholespy"
                return
        if backend != "scipy":
            raise ValueError(f"unknown backend {backend!r}")
        self._impl = sla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A")
        self.backend = "scipy"

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve ``A x = b`` for ``b`` of shape ``(n,)`` or ``(n, k)``."""
        b = np.ascontiguousarray(b, dtype=np.float64)
        if self.backend == "scipy":
            return self._impl.solve(b)
        squeeze = b.ndim == 1
        b2 = b[:, None] if squeeze else b
        x = np.zeros_like(b2)
        self._impl.solve(b2, x)
        return x[:, 0] if squeeze else x
