"""Jacobian-field deformation: APAP's first stage, and its exact closed form.

The deformed vertices solve (paper eq. 1, lines 150-156)::

    V*(J) = argmin_V ||L V - Gᵀ M J||² + λ ||K_a V - T_a||²
          = A⁻¹ (Lᵀ Gᵀ M J + λ K_aᵀ T_a),        A = LᵀL + λ K_aᵀ K_a

with ``G`` the per-face gradient, ``M`` the double-area mass and ``L = GᵀMG`` (see
:mod:`grt.geometry.operators`). ``A`` depends on neither ``J`` nor the targets, so it is factored
once per mesh. Handle targets ``T_h = V0[h] + theta`` are then met by changing ``J``:

* ``method="apap"`` — as APAP's public stage 1: ``J`` starts at ``G V0``, Adam (lr 1e-3, 300
  steps, float64) on the mean squared handle error. Only the handle rows of the solve enter the
  loss, so the forward and backward passes use the dense map ``R = K_h A⁻¹ Lᵀ Gᵀ M`` (H x 3F,
  from H solves) and its transpose; one sparse solve at the end gives the vertices. This is the
  same iteration as solving per Adam step, without 600 sparse solves per candidate.
* ``method="exact"`` — the smallest area-weighted change of ``J`` (``min ||ΔJ||²_M``) that meets the
  handle targets exactly. ``V*`` is affine in ``J`` and the minimizer is linear in ``theta``, so
  ``V = V0 + W theta`` with ``W`` (V x H, shared by the three axes) from 2H solves::

        Z = A⁻¹ K_hᵀ,  Y = L Z,  C = Yᵀ L Y  (= (GY)ᵀ M (GY), H x H),  W = A⁻¹ L L Y C⁻¹

  (derivation: ``ΔJ = M⁻¹Bᵀ(BM⁻¹Bᵀ)⁻¹theta`` with ``B = K_h A⁻¹ Lᵀ Gᵀ M`` and ``Bᵀ = M G Y``).

* ``method="smooth"`` — handles that move smooth regions, not single vertices (issue 12: a lone
  displaced vertex is a singular source of the Poisson model and drags a tent-shaped spike). Each
  handle ``h`` carries a smooth volumetric displacement field ``ψ_h(x) theta_h`` with
  ``ψ_h(x) = (1 - (|x - x_h| / r)²)³`` for ``|x - x_h| < r`` (C², compact; ``r = radius`` x the
  bounding-box diagonal). Euclidean, not geodesic: the two sides of a thin wall move together, so
  walls keep their thickness instead of being pushed through each other. The field changes the
  Jacobians, ``ΔJ = G u`` with ``u = Σ_h ψ_h theta_h``, and the anchored Poisson solve makes the
  vertices: ``V = V0 + A⁻¹ L L Ψ theta`` (``LᵀGᵀM G = L L``), so ``W = A⁻¹ L L Ψ`` (V x H, H solves).
  Where ``u`` vanishes at the anchors this reproduces ``u`` exactly; a *point* anchor inside a
  handle's region would pin a dimple into the bump, so those are released (kept: anchors outside
  every region, and every anchor with an anchor neighbour, i.e. the task's protected regions; at
  least three, for Procrustes). The released anchors are listed in :attr:`released_anchors`.

Anchors are soft (λ = 1 as APAP): with anchors at rest the rest field ``J0 = G V0`` reproduces ``V0``
exactly, and a deformation moves them slightly; ``ShapeDeformer`` rigidly re-aligns every result on
the anchors (Procrustes), as the paper does (lines 1068-1073).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import trimesh

from grt.geometry.mesh import UnitCubeFrame, align_to_anchors
from grt.geometry.operators import gradient_operator, laplacian, mass_matrix, selector_matrix
from grt.geometry.solver import SparseCholesky

METHODS = ("smooth", "exact", "apap")
DEFAULT_RADIUS = 0.35  # smooth method: handle region radius, fraction of the bounding-box diagonal
MIN_ANCHORS = 3


@dataclass(frozen=True)
class AdamConfig:
    """APAP stage-1 optimizer settings (torch.optim.Adam defaults for betas/eps)."""

    lr: float = 1e-3
    steps: int = 300
    beta1: float = 0.9
    beta2: float = 0.999
    eps: float = 1e-8


def check_indices(handles: np.ndarray, anchors: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate handle/anchor vertex indices; returns them as int64 arrays.

    Raises:
        ValueError: empty sets, non-integers, out-of-range or duplicate indices, or a vertex that is
            both a handle and an anchor (the message names the offending indices).
    """
    out = []
    for name, idx in (("handles", handles), ("anchors", anchors)):
        arr = np.asarray(idx)
        if arr.size == 0:
            raise ValueError(f"{name} is empty: give at least one {name[:-1]} vertex index")
        if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.integer):
            if np.issubdtype(arr.dtype, np.floating) and np.all(arr == np.round(arr)):
                arr = arr.astype(np.int64)
            else:
                raise ValueError(f"{name} must be a 1-D list of integer vertex indices, got {arr.dtype} "
                                 f"of shape {arr.shape}")
        bad = arr[(arr < 0) | (arr >= n_vertices)]
        if bad.size:
            raise ValueError(f"{name} out of range for a mesh with {n_vertices} vertices: "
                             f"{bad[:10].tolist()}")
        uniq, counts = np.unique(arr, return_counts=True)
        if np.any(counts > 1):
            raise ValueError(f"duplicate {name}: {uniq[counts > 1][:10].tolist()}")
        out.append(arr.astype(np.int64))
    both = np.intersect1d(out[0], out[1])
    if both.size:
        raise ValueError(f"vertices cannot be both handle and anchor: {both[:10].tolist()}")
    return out[0], out[1]


class JacobianFieldDeformer:
    """Map handle displacements to deformed vertices, batched over a population.

    Args:
        vertices: ``(V, 3)`` rest positions (GRT passes unit-cube coordinates).
        faces: ``(F, 3)`` triangles (no degenerate faces).
        handles: ``(H,)`` handle vertex indices.
        anchors: ``(A,)`` anchor vertex indices (at least one per connected component).
        lam: anchor weight λ (APAP: 1.0).
        method: ``"exact"`` (default), ``"smooth"`` or ``"apap"``.
        adam: optimizer settings of the ``"apap"`` method.
        radius: ``"smooth"`` method: each handle's region radius, a fraction of the bounding-box
            diagonal of ``vertices``.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, handles, anchors, lam: float = 1.0,
                 method: str = "exact", adam: AdamConfig | None = None, radius: float = DEFAULT_RADIUS):
        if method not in METHODS:
            raise ValueError(f"unknown method {method!r}; use one of {METHODS}")
        if not lam > 0:
            raise ValueError(f"lam must be > 0 (anchor weight), got {lam}")
        if not (isinstance(radius, (int, float)) and 0 < radius <= 1):
            raise ValueError(f"radius must be in (0, 1] (a fraction of the bounding-box diagonal), got {radius!r}")
        self.v0 = np.asarray(vertices, np.float64)
        self.faces = np.asarray(faces, np.int64)
        self.handles, self.anchors = check_indices(handles, anchors, len(self.v0))
        self.lam, self.method, self.adam, self.radius = float(lam), method, adam or AdamConfig(), float(radius)
        self.released_anchors = np.empty(0, np.int64)
        if method == "smooth":
            self.anchors, self.released_anchors = self._release_point_anchors()
        self._check_components()
        self.G = gradient_operator(self.v0, self.faces)
        self.M = mass_matrix(self.v0, self.faces)
        self.L = laplacian(self.G, self.M)
        self.Ka = selector_matrix(self.anchors, len(self.v0))
        A = (self.L.T @ self.L + self.lam * (self.Ka.T @ self.Ka)).tocsc()
        self.solver = SparseCholesky(A)
        # The anchors' fixed targets (their rest positions) enter every right-hand side.
        self._anchor_rhs = self.lam * (self.Ka.T @ self.v0[self.anchors])  # (V, 3)
        self._LtGtM = (self.L.T @ self.G.T @ self.M).tocsr()  # (V, 3F)
        self._W = {"exact": self._exact_basis, "smooth": self._smooth_basis}.get(method, lambda: None)()
        self._R: np.ndarray | None = None
        self._c: np.ndarray | None = None

    def set_anchor_targets(self, positions: np.ndarray) -> None:
        """Hold the anchors (softly) at ``positions`` ``(A, 3)`` instead of their rest positions.

        Only the right-hand side changes (no refactorization). With moved anchors the rest field no
        longer reproduces ``V0``; :meth:`__call__` in exact mode still returns ``V0 + W theta``, so
        callers add the offset of the rest field (see ``grt.deform.deform_to_targets``).
        """
        positions = np.asarray(positions, np.float64)
        if positions.shape != (self.anchors.size, 3) or not np.all(np.isfinite(positions)):
            raise ValueError(f"anchor targets must be finite with shape ({self.anchors.size}, 3), "
                             f"got {positions.shape}")
        self._anchor_rhs = self.lam * (self.Ka.T @ positions)
        self._R = self._c = None

    @property
    def num_handles(self) -> int:
        return int(self.handles.size)

    def _check_components(self) -> None:
        e = self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(self.v0),) * 2)
        n, labels = csgraph.connected_components(adj, directed=False)
        missing = sorted(set(range(n)) - set(labels[self.anchors].tolist()))
        if missing:
            raise ValueError(f"{len(missing)} of the mesh's {n} connected components have no anchor; the "
                             "Poisson system is singular there. Add an anchor on every component.")

    # ----------------------------------------------------------------------------- smooth mode
    @property
    def region_radius(self) -> float:
        """Handle region radius in the units of ``vertices``."""
        return self.radius * float(np.linalg.norm(np.ptp(self.v0, axis=0)))

    def region_weights(self) -> np.ndarray:
        """``Ψ`` ``(V, H)``: each handle's smooth falloff ``(1 - (d / r)²)³`` over Euclidean distance."""
        d2 = ((self.v0[:, None, :] - self.v0[self.handles][None]) ** 2).sum(-1) / self.region_radius**2
        return np.clip(1.0 - d2, 0.0, None) ** 3

    def _release_point_anchors(self) -> tuple[np.ndarray, np.ndarray]:
        """Anchors kept and released by the smooth method (see the module docstring)."""
        e = self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(len(self.v0),) * 2).tocsr()
        is_anchor = np.zeros(len(self.v0), bool)
        is_anchor[self.anchors] = True
        has_anchor_neighbour = (adj[self.anchors] @ is_anchor.astype(float)) > 0
        dist = np.linalg.norm(self.v0[self.anchors][:, None] - self.v0[self.handles][None], axis=2).min(1)
        release = (dist < self.region_radius) & ~has_anchor_neighbour
        if (~release).sum() < MIN_ANCHORS:  # keep back the farthest released ones for Procrustes
            order = np.flatnonzero(release)[np.argsort(-dist[release])]
            release[order[: MIN_ANCHORS - int((~release).sum())]] = False
        return self.anchors[~release], self.anchors[release]

    def _smooth_basis(self) -> np.ndarray:
        return self.solver.solve(self.L @ (self.L @ self.region_weights()))

    # ------------------------------------------------------------------------------ exact mode
    def _exact_basis(self) -> np.ndarray:
        Kh_t = np.zeros((len(self.v0), self.num_handles))
        Kh_t[self.handles, np.arange(self.num_handles)] = 1.0
        Z = self.solver.solve(Kh_t)  # (V, H)
        Y = self.L @ Z
        C = Y.T @ (self.L @ Y)
        C = 0.5 * (C + C.T)
        W = self.solver.solve(self.L @ (self.L @ Y))
        try:
            return np.linalg.solve(C, W.T).T  # W C⁻¹, (V, H)
        except np.linalg.LinAlgError as exc:
            raise ValueError("handle constraints are degenerate (singular handle Gram matrix); "
                             "use fewer or more separated handles") from exc

    @property
    def basis(self) -> np.ndarray:
        """``W`` ``(V, H)`` of the exact and smooth methods: ``V(theta) = V0 + W @ theta``."""
        if self._W is None:
            self._W = self._smooth_basis() if self.method == "smooth" else self._exact_basis()
        return self._W

    # ------------------------------------------------------------------------------- interface
    def __call__(self, thetas: np.ndarray) -> np.ndarray:
        """Deform for each candidate of a population.

        Args:
            thetas: ``(N, H, 3)`` (or ``(H, 3)``) handle displacements, in the units of ``vertices``.

        Returns:
            ``(N, V, 3)`` (or ``(V, 3)``) deformed vertices.
        """
        thetas = np.asarray(thetas, np.float64)
        single = thetas.ndim == 2
        if single:
            thetas = thetas[None]
        if thetas.ndim != 3 or thetas.shape[1:] != (self.num_handles, 3):
            raise ValueError(f"thetas must have shape (N, {self.num_handles}, 3), got {thetas.shape}")
        if not np.all(np.isfinite(thetas)):
            raise ValueError("thetas contain NaN or inf")
        out = self._apap(thetas) if self.method == "apap" else self._exact(thetas)
        return out[0] if single else out

    def _exact(self, thetas: np.ndarray) -> np.ndarray:
        # One (V, H) @ (H, 3) product per candidate into one preallocated array: a population in one
        # einsum (or one (V, H) @ (H, 3N) product) went to a threaded BLAS call and through transposed
        # copies, 30 ms for ten candidates where ten of these products take 0.2-0.4 ms
        # (docs/benchmarks.md, "Deformation"; python -m grt.bench deform measures both).
        basis = self.basis
        out = np.empty((len(thetas), *self.v0.shape))
        for n, theta in enumerate(thetas):
            np.matmul(basis, theta, out=out[n])
        out += self.v0
        return out

    def solve_vertices(self, J: np.ndarray) -> np.ndarray:
        """Poisson solve for a batch of Jacobian fields: ``(N, 3F, 3)`` -> ``(N, V, 3)``."""
        n = J.shape[0]
        rhs = self._LtGtM @ np.moveaxis(J, 0, 1).reshape(J.shape[1], 3 * n)  # (V, 3N)
        rhs += np.tile(self._anchor_rhs, (1, n))
        return np.moveaxis(self.solver.solve(rhs).reshape(len(self.v0), n, 3), 1, 0)

    def _handle_map(self) -> tuple[np.ndarray, np.ndarray]:
        """Handle rows of the Poisson solve: ``V[h] = R J + c`` with ``R = K_h A⁻¹ Lᵀ Gᵀ M`` (H, 3F).

        ``R`` comes from H solves (``A`` is symmetric, so ``R = (A⁻¹ K_hᵀ)ᵀ Lᵀ Gᵀ M``); the Adam loop
        then needs no sparse solve at all, only this dense (H x 3F) map and its transpose.
        """
        if self._R is None:
            Kh_t = np.zeros((len(self.v0), self.num_handles))
            Kh_t[self.handles, np.arange(self.num_handles)] = 1.0
            Z = self.solver.solve(Kh_t)  # (V, H)
            self._R = np.ascontiguousarray((self._LtGtM.T @ Z).T)  # (H, 3F)
            self._c = Z.T @ self._anchor_rhs  # (H, 3)
        return self._R, self._c

    def _apap(self, thetas: np.ndarray) -> np.ndarray:
        n, cfg = thetas.shape[0], self.adam
        R, c = self._handle_map()
        targets = self.v0[self.handles][None] + thetas  # (N, H, 3)
        J = np.repeat((self.G @ self.v0)[None], n, axis=0)  # (N, 3F, 3)
        m, v2 = np.zeros_like(J), np.zeros_like(J)
        scale = 2.0 / (3 * self.num_handles)  # d/dx of the mean over (H, 3) squared errors
        for step in range(1, cfg.steps + 1):
            g_h = scale * (np.matmul(R, J) + c - targets)  # (N, H, 3) dLoss/dV at the handles
            grad = np.matmul(R.T, g_h)  # (N, 3F, 3) = dLoss/dJ, the adjoint of the handle map
            m = cfg.beta1 * m + (1 - cfg.beta1) * grad
            v2 = cfg.beta2 * v2 + (1 - cfg.beta2) * grad * grad
            m_hat = m / (1 - cfg.beta1**step)
            v_hat = v2 / (1 - cfg.beta2**step)
            J = J - cfg.lr * m_hat / (np.sqrt(v_hat) + cfg.eps)
        return self.solve_vertices(J)


def deformer_options(cfg) -> dict:
    """``ShapeDeformer`` keyword arguments from a run's ``deformer`` config block (any mapping with
    ``get``); keys a run from before them lacks take the values that run was made with."""
    return {"lam": float(cfg.get("lam", 1.0)), "method": str(cfg.get("method", "exact")),
            "radius": float(cfg.get("radius", DEFAULT_RADIUS))}


class ShapeDeformer:
    """Deform a metric mesh: unit-cube normalization, Jacobian-field solve, rescale, Procrustes.

    This is the deformation operator ``D_theta`` of the paper as GRT uses it: ``theta`` are handle
    displacements in unit-cube units (the paper's σ = 0.001 is in these units); the result is in
    meters and rigidly aligned to the nominal mesh on the anchors (paper lines 1068-1073).

    Args:
        mesh: nominal mesh in meters (validated, see :func:`grt.geometry.mesh.load_mesh`).
        handles, anchors, lam, method, adam, radius: as :class:`JacobianFieldDeformer`.
        align: Procrustes-align results on the anchors (needs >= 3 anchors; with fewer, only the
            anchors' centroid is matched).
    """

    def __init__(self, mesh: trimesh.Trimesh, handles, anchors, lam: float = 1.0, method: str = "exact",
                 adam: AdamConfig | None = None, align: bool = True, radius: float = DEFAULT_RADIUS):
        self.mesh = mesh
        self.faces = np.asarray(mesh.faces)
        self.frame = UnitCubeFrame.fit(np.asarray(mesh.vertices))
        self.v0_unit = self.frame.to_unit(np.asarray(mesh.vertices, np.float64))
        self.core = JacobianFieldDeformer(self.v0_unit, self.faces, handles, anchors, lam, method, adam, radius)
        self.align = align

    @property
    def handles(self) -> np.ndarray:
        return self.core.handles

    @property
    def anchors(self) -> np.ndarray:
        """The anchors the solve holds (the smooth method may have released some)."""
        return self.core.anchors

    @property
    def released_anchors(self) -> np.ndarray:
        return self.core.released_anchors

    @property
    def meters_per_unit(self) -> float:
        return self.frame.scale

    def vertices(self, thetas: np.ndarray) -> np.ndarray:
        """``(N, H, 3)`` unit-cube displacements -> ``(N, V, 3)`` deformed vertices in meters."""
        thetas = np.asarray(thetas, np.float64)
        single = thetas.ndim == 2
        unit = self.core(thetas[None] if single else thetas)
        if self.align:
            ref = self.v0_unit[self.anchors]
            if len(self.anchors) >= 3:
                unit = align_to_anchors(unit, self.anchors, ref)
            else:
                unit = unit + (ref.mean(0) - unit[:, self.anchors].mean(1))[:, None, :]
        out = self.frame.to_metric(unit)
        return out[0] if single else out

    def meshes(self, thetas: np.ndarray) -> list[trimesh.Trimesh]:
        """Deformed meshes in meters, one per candidate (same faces as the nominal mesh)."""
        thetas = np.asarray(thetas, np.float64)
        batch = thetas[None] if thetas.ndim == 2 else thetas
        return [trimesh.Trimesh(v, self.faces, process=False) for v in self.vertices(batch)]
