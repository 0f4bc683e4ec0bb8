"""The paper's metrics on continuous scores (a drawer opening in meters), and the score intervals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grt import metrics

NAN = float("nan")
# S0 = 0.35 m; iteration minima 0.30, 0.12, 0.05 m (one unscorable candidate, NaN, is skipped).
S0 = 0.35
ITERATIONS = [[0.34, 0.30, 0.41], [0.12, 0.33], [0.05, 0.20, NAN]]


def test_continuous_metrics_hand_computed():
    # C(t) = (S0 - S_t) / S0 = 0, 0.05/0.35 = 1/7, 0.23/0.35 = 23/35, 0.30/0.35 = 6/7
    curve = metrics.degradation_curve(S0, ITERATIONS)
    assert curve.tolist() == pytest.approx([0.0, 1 / 7, 23 / 35, 6 / 7])
    assert metrics.final_drop(S0, ITERATIONS) == pytest.approx(6 / 7)
    # trapezoids: (0 + 5/35)/2 + (5/35 + 23/35)/2 + (23/35 + 30/35)/2 = (5 + 28 + 53) / 70
    assert metrics.auc(curve) == pytest.approx(86 / 70)
    assert metrics.iter_at_50(curve) == (2, True)  # 0.12 m <= 0.175 m = S0 / 2 first at t = 2
    summary = metrics.summarize(S0, ITERATIONS)
    assert summary["final_drop"] == pytest.approx(6 / 7) and summary["auc"] == pytest.approx(86 / 70)
    assert summary["iter_at_50"] == 2 and summary["reached_50"] is True


def test_half_of_s0_exactly_counts_as_reached():
    curve = metrics.degradation_curve(S0, [[0.2], [0.175]])
    assert metrics.iter_at_50(curve) == (2, True)


def test_metrics_do_not_depend_on_the_unit_or_range():
    """The same openings in centimeters (scores far above 1) give the same relative metrics."""
    in_cm = [[100 * s for s in it] for it in ITERATIONS]
    expected = metrics.summarize(S0, ITERATIONS)["curve"]
    assert metrics.summarize(100 * S0, in_cm)["curve"] == pytest.approx(expected)
    assert metrics.summarize(100 * S0, in_cm)["auc"] == pytest.approx(86 / 70)


def test_a_candidate_above_s0_is_no_drop():
    curve = metrics.degradation_curve(S0, [[0.5, 0.41]])  # a wider opening than the nominal one
    assert curve.tolist() == pytest.approx([0.0, 0.0])
    assert metrics.iter_at_50(curve) == (1, False)


@pytest.mark.parametrize("s0", [0.0, -0.02])
def test_non_positive_s0_has_no_relative_drop(s0):
    """A negative S0 would flip the sign of every relative drop: undefined like S0 = 0."""
    s = metrics.summarize(s0, [[s0 - 0.01]])
    assert math.isnan(s["final_drop"]) and s["curve"] == [None, None]


def test_delta_complexity_of_continuous_scores():
    # The three lowest openings (0.05, 0.12, 0.20 m) have entropy +0.3, +0.1, +0.2 over the nominal 4.0.
    cands = [(0.30, 9.0), (0.05, 4.3), (0.41, 9.0), (0.12, 4.1), (0.20, 4.2), (NAN, 0.0)]
    assert metrics.delta_complexity(4.0, cands, k=3) == pytest.approx(0.2)


def test_bootstrap_interval_is_deterministic_by_seed():
    values = np.random.default_rng(3).gamma(2.0, 0.05, size=40)  # skewed openings, m
    a, b = metrics.bootstrap_interval(values), metrics.bootstrap_interval(values, seed=0)
    assert a == b
    assert metrics.bootstrap_interval(values, seed=1) != a
    low, high = a
    assert values.min() < low < values.mean() < high < values.max()


def test_bootstrap_interval_matches_the_normal_one_for_many_values():
    values = np.random.default_rng(0).normal(0.3, 0.05, size=400)
    boot, normal = metrics.bootstrap_interval(values), metrics.mean_interval(values)
    assert boot == pytest.approx(normal, abs=0.1 * (normal[1] - normal[0]))


def test_bootstrap_interval_edge_cases():
    assert metrics.bootstrap_interval([0.2, 0.2, 0.2]) == pytest.approx((0.2, 0.2))
    assert metrics.bootstrap_interval([0.31]) == pytest.approx((0.31, 0.31))
    assert all(math.isnan(x) for x in metrics.bootstrap_interval([]))
    with pytest.raises(ValueError, match="n_boot"):
        metrics.bootstrap_interval([0.1, 0.2], n_boot=0)


def test_score_interval_auto_is_wilson_for_0_1_scores_else_normal():
    binary, continuous = [1.0, 0.0, 1.0, 1.0], [0.31, 0.28, 0.35, 0.02]
    assert metrics.score_interval(binary) == metrics.wilson_interval(3, 4)
    assert metrics.score_interval(continuous) == metrics.mean_interval(continuous)
    assert metrics.score_interval(continuous, "auto") == metrics.mean_interval(continuous)


def test_score_interval_explicit_methods():
    binary, continuous = [1.0, 0.0, 1.0, 1.0], [0.31, 0.28, 0.35, 0.02]
    assert metrics.score_interval(binary, "wilson") == metrics.wilson_interval(3, 4)
    assert metrics.score_interval(binary, "normal") == metrics.mean_interval(binary)
    assert metrics.score_interval(continuous, "bootstrap") == metrics.bootstrap_interval(continuous)
    for method in metrics.CI_METHODS:
        assert all(math.isnan(x) for x in metrics.score_interval([], method))


def test_score_interval_refuses_wilson_on_continuous_scores_and_unknown_methods():
    with pytest.raises(ValueError, match="0 or 1"):
        metrics.score_interval([0.31, 0.28], "wilson")
    with pytest.raises(ValueError, match="auto, wilson, normal, bootstrap"):
        metrics.score_interval([0.31], "student")


def test_the_wilson_interval_always_holds_the_observed_proportion():
    for n in range(1, 129):
        for k in (0, n // 3, n // 2, n):
            low, high = metrics.wilson_interval(k, n)
            assert 0.0 <= low <= k / n <= high <= 1.0, (k, n, low, high)
        assert metrics.wilson_interval(n, n)[1] == 1.0 and metrics.wilson_interval(0, n)[0] == 0.0
