"""Angular-deficit entropy and Chamfer distance."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grt.geometry.chamfer import chamfer_distance
from grt.geometry.complexity import angular_deficit_entropy, angular_deficits, delta_complexity
from grt.objects import get_object


def test_deficits_sum_to_4pi_on_closed_genus0_mesh():
    assert abs(angular_deficits(trimesh.creation.icosphere(2)).sum() - 4 * np.pi) < 1e-9


def test_entropy_orders_smooth_sharp_and_irregular_shapes(rng):
    sphere = trimesh.creation.icosphere(4)
    box = get_object("sugar_box")
    noisy = sphere.copy()
    noisy.vertices *= 1 + 0.02 * rng.standard_normal((len(noisy.vertices), 1))
    h = {name: angular_deficit_entropy(m) for name, m in
         [("sphere", sphere), ("box", box), ("mug", get_object("mug")), ("noisy", noisy)]}
    assert h["sphere"] < 0.05  # constant curvature: every deficit in one bin
    assert h["sphere"] < h["box"] < h["mug"] < h["noisy"], h


def test_delta_complexity_is_median_change(rng):
    nominal = trimesh.creation.icosphere(3)
    noisy = []
    for s in (0.0, 0.01, 0.05):
        m = nominal.copy()
        m.vertices *= 1 + s * rng.standard_normal((len(m.vertices), 1))
        noisy.append(m)
    h0 = angular_deficit_entropy(nominal)
    expected = np.median([angular_deficit_entropy(m) - h0 for m in noisy])
    assert delta_complexity(nominal, noisy) == pytest.approx(expected)
    assert delta_complexity(nominal, [nominal]) == 0.0
    with pytest.raises(ValueError):
        delta_complexity(nominal, [])


def test_chamfer_points_known_value_and_symmetry():
    a = np.zeros((1, 3))
    b = np.array([[0.0, 0.0, 0.1]])
    assert chamfer_distance(a, b) == pytest.approx(0.02)  # 0.1² each way
    assert chamfer_distance(a, b, squared=False) == pytest.approx(0.2)
    assert chamfer_distance(a, b) == chamfer_distance(b, a)


def test_chamfer_meshes_identical_zero_shifted_positive():
    m = trimesh.creation.icosphere(2)
    assert chamfer_distance(m, m, samples=2000) == 0.0
    shifted = m.copy()
    shifted.apply_translation([0.01, 0, 0])
    assert 0 < chamfer_distance(m, shifted, samples=2000) < 3e-4
    with pytest.raises(ValueError, match="shape"):
        chamfer_distance(np.zeros((0, 3)), m)
