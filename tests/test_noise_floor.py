"""The noise floor of Final Drop, the ranking of CrashShapes by the lower bound of their drop, and the paired
interval of a confirmed drop: each checked against an independent simulation or a hand count."""

from __future__ import annotations

import numpy as np
import pytest

from grt.confirm import paired_drop_interval
from grt.noise_floor import fixed_p_floor, noise_floor, simulated_candidates
from grt.ranking import drop_lower_bound, ranked


def _simulated_null(p: float, candidates: int, trials: int, s0: float, draws: int = 200_000) -> np.ndarray:
    """Null Final Drops by brute force: the lowest of ``candidates`` binomial means, against a fixed S0."""
    lowest = np.random.default_rng(1).binomial(trials, p, size=(draws, candidates)).min(axis=1) / trials
    return np.maximum(0.0, (s0 - lowest) / s0)


@pytest.mark.parametrize(("p", "candidates", "trials"), [(0.75, 64, 8), (0.5, 16, 8), (0.96, 100, 64)])
def test_the_exact_floor_matches_a_brute_force_simulation(p, candidates, trials):
    mean, q95 = fixed_p_floor(p, candidates, trials)
    null = _simulated_null(p, candidates, trials, p)
    assert mean == pytest.approx(null.mean(), abs=0.005)
    assert q95 == pytest.approx(np.quantile(null, 0.95, method="inverted_cdf"), abs=1e-9)


def test_a_perfect_nominal_does_not_prove_a_perfect_policy():
    """8/8 on the nominal: p is not known to be 1, so 64 candidates of 8 trials still show a drop by luck."""
    floor = noise_floor([1.0] * 8, candidates=64, trials=8, observed=0.625)
    assert 0.15 < floor["mean"] < 0.4 and floor["q95"] >= 0.5
    assert 0.0 < floor["p_value"] < 0.2
    many = noise_floor([1.0] * 512, candidates=64, trials=8)  # 512/512: p near 1, the floor near 0
    assert many["mean"] < 0.05 < floor["mean"]
    # the floor grows with the candidates searched and shrinks with the trials behind each score
    assert noise_floor([1.0] * 6 + [0.0] * 2, 100, 8)["mean"] > noise_floor([1.0] * 6 + [0.0] * 2, 10, 8)["mean"]
    assert noise_floor([1.0] * 6 + [0.0] * 2, 64, 64)["mean"] < noise_floor([1.0] * 6 + [0.0] * 2, 64, 8)["mean"]


def test_a_continuous_floor_bootstraps_the_nominals_trials_and_is_repeatable():
    openings = np.random.default_rng(0).uniform(0.05, 0.2, 16)
    floor = noise_floor(openings, candidates=30, trials=8, observed=0.9, seed=3)
    assert floor == noise_floor(openings, candidates=30, trials=8, observed=0.9, seed=3)
    assert "bootstrap" in floor["method"] and 0.1 < floor["mean"] < floor["q95"] < 0.9
    assert floor["p_value"] < 0.01
    # a bootstrap null by hand: the lowest of 30 means of 8 draws with replacement
    rng = np.random.default_rng(7)
    lowest = openings[rng.integers(0, 16, size=(4000, 30, 8))].mean(axis=2).min(axis=1)
    assert floor["mean"] == pytest.approx(np.mean(1 - lowest / openings.mean()), abs=0.01)


def test_no_floor_without_a_positive_s0_or_a_search():
    assert np.isnan(noise_floor([0.0] * 8, 64, 8)["mean"])
    assert np.isnan(noise_floor([1.0] * 8, 0, 8, observed=0.5)["p_value"])


def test_the_candidates_counted_are_those_simulated():
    records = [{"iteration": 0, "score": 1.0, "trials": [{}]},
               {"iteration": 1, "score": 0.5, "trials": [{}]},
               {"iteration": 1, "score": float("nan"), "trials": []},  # implausible: never simulated
               {"iteration": 1, "score": float("nan"), "trials": [{}]},  # every trial a simulator error
               {"iteration": 2, "score": float("nan"), "trials": [{}], "race": {"stopped": "cannot_rank"}}]
    assert simulated_candidates(records) == 2


def _rec(i: int, score: float, hi: float) -> dict:
    return {"iteration": 1, "candidate": i, "score": score, "ci95": [0.0, hi]}


def test_crashshapes_are_ranked_by_the_lower_bound_of_their_drop():
    # 0/6 valid trials (two simulator errors) has less evidence than 0/8: Wilson's upper end 0.39 vs 0.32
    few, full, one = _rec(0, 0.0, 0.390), _rec(1, 0.0, 0.324), _rec(2, 0.125, 0.471)
    assert [r["candidate"] for r in ranked([few, one, full])] == [1, 0, 2]
    assert drop_lower_bound(full, 1.0) == pytest.approx(0.676)
    # equal evidence: the observed order, earliest first among ties
    assert [r["candidate"] for r in ranked([_rec(3, 0.5, 0.8), _rec(2, 0.5, 0.8), _rec(1, 0.25, 0.6)])] == [1, 2, 3]
    assert ranked([_rec(0, float("nan"), float("nan"))]) == []


def test_the_confirmed_drop_interval_is_paired_and_never_degenerate():
    nominal, shape = np.ones(32), np.zeros(32)
    low, high = paired_drop_interval(shape, nominal)
    assert 0.8 < low < high <= 1.0 and high > 0.99
    same = paired_drop_interval(nominal, nominal)
    assert same[0] < 0 < same[1]
    # pairing matters: the same two success rates, disagreeing on few episodes or on many
    a = np.r_[np.ones(24), np.zeros(8)]
    tight = paired_drop_interval(np.r_[np.ones(16), np.zeros(16)], a)
    loose = paired_drop_interval(np.r_[np.ones(8), np.zeros(16), np.ones(8)], a)  # 24 discordant, not 8
    assert tight[1] - tight[0] < loose[1] - loose[0]
    assert paired_drop_interval(shape, nominal, seed=4) == paired_drop_interval(shape, nominal, seed=4)
