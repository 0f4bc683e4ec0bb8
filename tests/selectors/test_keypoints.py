"""The heuristic keypoint sampler (paper appendix, lines 819-855) and the panel's viewpoints."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grt.selectors.keypoints import SYMMETRIC, principal_axes, prune, sample_keypoints
from grt.selectors.panel import diverse_views, hemisphere_views


def _pairwise(points: np.ndarray) -> np.ndarray:
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    return d + np.eye(len(points)) * 1e9


@pytest.mark.parametrize("name", ["sphere", "box"])
def test_count_separation_and_surface(name, request):
    mesh = request.getfixturevalue(name)
    kp = sample_keypoints(mesh, num_keypoints=25, delta=0.1)
    assert 15 <= len(kp) <= 25
    assert len(np.unique(kp.vertices)) == len(kp)
    assert _pairwise(kp.positions).min() >= 0.1  # unit-cube units
    # keypoints are mesh vertices, so they lie on the surface; positions are in the unit-cube frame
    np.testing.assert_allclose(kp.frame.to_metric(kp.positions), mesh.vertices[kp.vertices], atol=1e-12)
    _, dist, _ = trimesh.proximity.closest_point(mesh, mesh.vertices[kp.vertices])
    assert dist.max() < 1e-9
    assert set(kp.stages) <= {"symmetric", "axis"} and (kp.stages == SYMMETRIC).sum() >= 5


def test_deterministic_and_input_untouched(sphere):
    before = sphere.vertices.copy()
    a, b = sample_keypoints(sphere, seed=3), sample_keypoints(sphere, seed=3)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(sphere.vertices, before)


def test_symmetric_pairs_on_a_symmetric_object(box):
    kp = sample_keypoints(box, seed=0)
    center = kp.frame.to_unit(box.vertices).mean(0)  # the box is symmetric about its centroid
    P = kp.positions - center
    sym = P[kp.stages == SYMMETRIC]
    partnered = 0
    for p in sym:
        mirrors = [p - 2.0 * (v @ p) * v for v in kp.axes]
        partnered += min(np.linalg.norm(P - m, axis=1).min() for m in mirrors) < 0.05
    assert partnered >= 0.75 * len(sym)


def test_principal_axes_right_handed(rng):
    points = rng.normal(size=(2000, 3)) * [5.0, 2.0, 0.5]
    axes = principal_axes(points)
    np.testing.assert_allclose(axes @ axes.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(axes) == pytest.approx(1.0)
    assert abs(axes[0, 0]) > 0.99 and abs(axes[1, 1]) > 0.99


def test_prune_keeps_separated_points():
    pts = np.array([[0, 0, 0], [0.05, 0, 0], [0.2, 0, 0], [0.25, 0, 0], [1, 1, 1]], float)
    np.testing.assert_array_equal(prune(pts, 0.1), [0, 2, 4])


def test_hemisphere_views_follow_the_paper():
    views = hemisphere_views(10)
    assert views.shape == (10, 2)
    np.testing.assert_allclose(views[0], [0.0, 81.0])
    np.testing.assert_allclose(views[9], [162.0, -81.0])
    picked = diverse_views(views, 4)
    assert len(set(picked.tolist())) == 4
