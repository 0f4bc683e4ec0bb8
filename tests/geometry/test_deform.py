"""Jacobian-field deformer: rest reproduction, constraints, batching, operators, Procrustes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import Delaunay

from grt.geometry.chamfer import chamfer_distance
from grt.geometry.deform import JacobianFieldDeformer, ShapeDeformer
from grt.geometry.mesh import procrustes
from grt.geometry.operators import gradient_operator, laplacian, mass_matrix
from grt.objects import get_object


@pytest.fixture(scope="module")
def sphere():
    m = trimesh.creation.icosphere(3, radius=0.5)
    v = np.asarray(m.vertices)
    handles = np.flatnonzero(v[:, 2] > 0.45)[:4]
    anchors = np.flatnonzero(v[:, 2] < -0.3)
    return v, np.asarray(m.faces), handles, anchors


@pytest.mark.parametrize("method, atol", [("exact", 1e-9), ("apap", 1e-4)])
def test_rest_targets_reproduce_rest_mesh(sphere, method, atol):
    # Adam normalizes the gradient, so round-off-sized gradients at rest still move J by ~lr per
    # step: the faithful APAP mode reproduces the rest mesh only to ~1e-5 (unit-size mesh).
    v, f, h, a = sphere
    d = JacobianFieldDeformer(v, f, h, a, method=method)
    np.testing.assert_allclose(d(np.zeros((len(h), 3))), v, atol=atol)
    np.testing.assert_allclose(d.solve_vertices((d.G @ v)[None])[0], v, atol=1e-9)


def test_exact_meets_handles_and_anchors_stay(sphere, rng):
    v, f, h, a = sphere
    d = JacobianFieldDeformer(v, f, h, a, method="exact")
    theta = 0.03 * rng.standard_normal((len(h), 3))
    out = d(theta)
    assert np.abs(out[h] - (v[h] + theta)).max() <= 1e-8
    drift = np.abs(out[a] - v[a]).max()
    assert drift < 0.1 * np.abs(theta).max(), f"anchor drift {drift:.2e} (soft anchors, lambda = 1)"


def test_batched_equals_one_by_one(sphere, rng):
    v, f, h, a = sphere
    thetas = 0.02 * rng.standard_normal((3, len(h), 3))
    for method in ("exact", "apap"):
        d = JacobianFieldDeformer(v, f, h, a, method=method, adam=None)
        batch = d(thetas)
        single = np.stack([d(t) for t in thetas])
        np.testing.assert_allclose(batch, single, atol=1e-10)


def test_apap_handle_map_matches_sparse_solve(sphere, rng):
    v, f, h, a = sphere
    d = JacobianFieldDeformer(v, f, h, a, method="apap")
    J = (d.G @ v)[None] + 0.01 * rng.standard_normal((1, 3 * len(f), 3))
    R, c = d._handle_map()
    np.testing.assert_allclose(R @ J[0] + c, d.solve_vertices(J)[0, h], atol=1e-10)


def test_linear_functions_in_kernel_of_laplacian(sphere):
    v, f, _, _ = sphere
    L = laplacian(gradient_operator(v, f), mass_matrix(v, f))
    assert np.abs(L @ np.ones(len(v))).max() < 1e-9  # constants, on any mesh
    # Linear functions: in the kernel at interior vertices of a flat (triangulated, irregular) patch.
    rng = np.random.default_rng(1)
    pts = np.concatenate([rng.random((200, 2)), [[0, 0], [1, 0], [0, 1], [1, 1]]])
    tri = trimesh.Trimesh(np.c_[pts, np.zeros(len(pts))], Delaunay(pts).simplices)
    Lp = laplacian(gradient_operator(tri.vertices, tri.faces), mass_matrix(tri.vertices, tri.faces))
    interior = np.setdiff1d(np.arange(len(pts)), np.unique(tri.edges[trimesh.grouping.group_rows(tri.edges_sorted, require_count=1)]))
    x = pts @ np.array([0.3, -1.2])
    assert np.abs((Lp @ x)[interior]).max() < 1e-9


def test_exact_and_apap_close_on_small_mesh(sphere, rng):
    v, f, h, a = sphere
    theta = 0.01 * rng.standard_normal((len(h), 3))
    ve = JacobianFieldDeformer(v, f, h, a, method="exact")(theta)
    va = JacobianFieldDeformer(v, f, h, a, method="apap")(theta)
    cd = chamfer_distance(trimesh.Trimesh(ve, f), trimesh.Trimesh(va, f), samples=4000)
    # Different deformation models (Adam-300 does not land on the minimal change): close, not equal.
    # The paper's APAP-vs-Jacobian gap is 6.9e-4 (unit box).
    assert cd < 1e-3, f"Chamfer exact vs apap {cd:.2e} (squared, unit-size sphere)"


def test_procrustes_recovers_rigid_motion(rng):
    src = rng.standard_normal((50, 3))
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    R_true = q * np.sign(np.linalg.det(q))
    t_true = np.array([0.1, -0.2, 0.3])
    R, t = procrustes(src, src @ R_true.T + t_true)
    np.testing.assert_allclose(R, R_true, atol=1e-10)
    np.testing.assert_allclose(t, t_true, atol=1e-10)


def test_shape_deformer_metric_output_and_alignment(rng):
    mesh = get_object("can")
    v = np.asarray(mesh.vertices)
    d = ShapeDeformer(mesh, np.argsort(-v[:, 2])[:3], np.flatnonzero(v[:, 2] < 0.01))
    out = d.vertices(np.zeros((2, 3, 3)))
    np.testing.assert_allclose(out[0], v, atol=1e-9)
    moved = d.meshes(0.02 * rng.standard_normal((3, 3)))[0]
    assert moved.is_watertight and abs(moved.extents[2] - mesh.extents[2]) < 0.02


@pytest.mark.parametrize("handles, anchors, match", [
    ([0, 10**6], [5], "out of range"), ([0, 0], [5], "duplicate"), ([0, 1], [1, 5], "both handle and anchor"),
    ([], [5], "empty"), ([0.5], [5], "integer"),
])
def test_bad_indices_rejected(sphere, handles, anchors, match):
    v, f, _, _ = sphere
    with pytest.raises(ValueError, match=match):
        JacobianFieldDeformer(v, f, handles, anchors)


def test_nan_theta_rejected(sphere):
    v, f, h, a = sphere
    d = JacobianFieldDeformer(v, f, h, a)
    with pytest.raises(ValueError, match="NaN"):
        d(np.full((len(h), 3), np.nan))
