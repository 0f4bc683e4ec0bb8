"""CandidateResult figures and intervals."""

from __future__ import annotations

import math

import pytest

from grt.evaluators.base import CandidateResult
from grt.evaluators.pool import sim_error
from grt.tasks.base import TrialOutcome


def _trial(seed: int, ok: bool) -> TrialOutcome:
    return TrialOutcome(seed, float(ok), ok, "success" if ok else "missed", {})


def test_candidate_result_excludes_sim_errors():
    trials = [_trial(1, True), _trial(2, False), _trial(3, True), sim_error(4, "boom")]
    result = CandidateResult.from_trials(trials, wall_s=2.5)
    assert result.score == pytest.approx(2 / 3)
    assert result.success_rate == pytest.approx(2 / 3)
    assert result.outcomes == {"success": 2, "missed": 1, "sim_error": 1}
    assert result.sim_errors == 1
    low, high = result.ci95()
    assert low < 2 / 3 < high
    summary = result.summary()
    assert summary["trials"] == 4 and summary["wall_s"] == 2.5


def test_all_errors_give_nan_score():
    result = CandidateResult.from_trials([sim_error(1, "x")], wall_s=0.0)
    assert math.isnan(result.score) and math.isnan(result.success_rate)


def test_continuous_scores_use_normal_interval():
    trials = [TrialOutcome(i, s, s > 0.5, "success", {}) for i, s in enumerate([0.2, 0.4, 0.6, 0.8])]
    low, high = CandidateResult.from_trials(trials, 1.0).ci95()
    assert low < 0.5 < high and low > -1.0
    assert math.isnan(CandidateResult.from_trials([sim_error(1, "x")], 0.0).ci95()[0])
