"""The racing rule (grt/racing.py): what it stops, and the exact risk of stopping a candidate that matters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grt.racing import NOT_CRASH, NOT_TOP_K, Race, _risk, failures_needed, kth_best, look_level, looks


def test_looks_split_the_trials_in_rounds_and_never_look_after_the_last():
    assert looks(8, 8) == (1, 2, 3, 4, 5, 6, 7)
    assert looks(64, 8) == (8, 16, 24, 32, 40, 48, 56)
    assert looks(2, 8) == (1,)  # at most one round per trial
    assert looks(1, 8) == ()


def test_failures_needed_follows_the_crashshape_margin_and_the_top_k():
    assert failures_needed(8, 1.0, 0.1, None) == 1  # 7/8 is a 12.5% drop: a CrashShape
    assert failures_needed(64, 1.0, 0.1, None) == 7  # 57/64 = 0.89
    assert failures_needed(8, 1.0, 0.1, 0.5) == 5  # must beat 0.5 strictly: 3/8
    assert failures_needed(8, 1.0, 0.1, 0.0) is None  # nothing beats a score of 0


@pytest.mark.parametrize(("total", "rounds"), [(8, 8), (64, 8), (128, 8), (32, 4)])
def test_a_candidate_that_matters_is_stopped_with_probability_at_most_alpha(total, rounds):
    at = looks(total, rounds)
    for bad in range(1, total + 1, max(1, total // 8)):
        bounds = look_level(total, bad, at, 0.05)
        assert _risk(total, bad, at, list(bounds)) <= 0.05 + 1e-12
        # more failures than the borderline one: stopped even less often (the borderline is the worst case)
        if bad < total:
            assert _risk(total, bad + 1, at, list(bounds)) <= _risk(total, bad, at, list(bounds)) + 1e-12


def test_the_risk_is_exact_against_a_simulation_of_random_seed_orders():
    total, bad, at = 16, 6, looks(16, 4)
    bounds = look_level(total, bad, at, 0.1)
    rng = np.random.default_rng(0)
    stops = 0
    for _ in range(20000):
        order = rng.permutation(np.r_[np.ones(bad), np.zeros(total - bad)])
        stops += any(order[:n].sum() <= most for n, most in zip(at, bounds, strict=True))
    assert math.isclose(stops / 20000, _risk(total, bad, at, list(bounds)), abs_tol=0.01)


def test_alpha_zero_stops_only_what_cannot_matter_even_if_every_remaining_trial_fails():
    race = Race(8, 8, 0.0, 1.0, 0.1, kth=0.5)  # must end with >= 5 failures of 8
    assert race.stop([1, 1, 1]) is None  # 3 successes: 5 failures are still possible
    verdict = race.stop([1, 1, 1, 1])  # 4 successes: at most 4 failures left
    assert verdict == {"stopped": NOT_TOP_K, "needed": 5, "failures": 0}
    assert race.stop([0, 1, 1, 1]) is None


def test_a_statistical_stop_comes_earlier_and_names_its_reason():
    assert Race(8, 8, 0.05, 1.0, 0.1, kth=0.5).stop([1, 1, 1])["stopped"] == NOT_TOP_K
    race = Race(64, 8, 0.05, 1.0, 0.1)  # no top-k yet: the CrashShape margin alone (7 failures of 64)
    assert race.stop([1] * 16) is None
    assert race.stop([1] * 24)["stopped"] == NOT_CRASH
    assert Race(8, 8, 0.05, 1.0, 0.1).stop([1] * 7) is None  # 1 failure of 8 is a CrashShape: never stopped


def test_a_candidate_with_a_simulator_error_is_never_stopped():
    assert Race(8, 8, 0.0, 1.0, 0.1, kth=0.5).stop([1, 1, 1], errors=1) is None


def test_kth_best_reads_full_trial_crashshapes_of_earlier_iterations_only():
    recs = [{"iteration": 0, "score": 1.0}, {"iteration": 1, "score": 0.5}, {"iteration": 1, "score": float("nan")},
            {"iteration": 2, "score": 0.25}, {"iteration": 2, "score": 0.95}, {"iteration": 3, "score": 0.0}]
    assert kth_best(recs, 2, 1.0, 0.1, before=3) == 0.5
    assert kth_best(recs, 2, 1.0, 0.1, before=2) is None
    assert kth_best(recs, 1, 1.0, 0.1, before=4) == 0.0


def test_the_rule_equals_its_reference_computation():
    """:func:`look_level` (tails and states that matter only) gives the bounds of the rule's definition computed
    the straightforward way (``grt.bench.racing.reference_look_level``), and the same exact risk."""
    from grt.bench.racing import reference_look_level, reference_risk

    for total, rounds in ((5, 4), (13, 3), (32, 8), (64, 8), (100, 4), (128, 8)):
        at = looks(total, rounds)
        for bad in range(1, total + 1, max(1, total // 10)):
            for alpha in (0.0, 0.01, 0.05, 0.3):
                bounds = look_level(total, bad, at, alpha)
                assert bounds == reference_look_level(total, bad, at, alpha), (total, rounds, bad, alpha)
                assert math.isclose(_risk(total, bad, at, list(bounds)), reference_risk(total, bad, at, list(bounds)),
                                    rel_tol=1e-12, abs_tol=1e-15)


def test_a_run_racing_4096_trials_a_candidate_does_not_wait_on_the_rule(tmp_path):
    """``budget.racing=true budget.trials=1024`` spent ~90 s per candidate in the main process computing the rule
    while the workers idled (minutes at 1024, hours at the drawer protocol's 4096); a toy run of 4096 trials a
    candidate now finishes, with raced candidates, well within the command's time limit."""
    from tests.cli.test_run_faults import RUN, grt_run

    run_dir = tmp_path / "run"
    res = grt_run(*RUN, "budget.racing=true", "budget.trials=4096", f"hydra.run.dir={run_dir}")
    assert res.returncode == 0, res.stderr[-3000:]
    import json

    records = [json.loads(line) for line in (run_dir / "journal.jsonl").read_text().splitlines()]
    assert len(records) == 7 and any((r.get("race") or {}).get("stopped") for r in records)
