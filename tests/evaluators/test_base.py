"""CandidateResult figures and intervals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grt import metrics
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


def _openings(values: list[float]) -> CandidateResult:
    """A drawer-like candidate: per-trial openings in meters, one sim_error (excluded)."""
    trials = [TrialOutcome(i, v, v > 0.3, "success" if v > 0.3 else "jammed", {})
              for i, v in enumerate(values)]
    return CandidateResult.from_trials([*trials, sim_error(99, "boom")], 1.0)


def test_ci95_takes_the_task_ci_method():
    values = [0.35, 0.31, 0.12, 0.33, 0.05, 0.34]
    result = _openings(values)
    assert result.score == pytest.approx(np.mean(values))
    assert result.ci95() == metrics.mean_interval(values)  # auto on continuous scores: normal
    assert result.ci95("normal") == metrics.mean_interval(values)
    assert result.ci95("bootstrap") == metrics.bootstrap_interval(values)
    with pytest.raises(ValueError, match="0 or 1"):
        result.ci95("wilson")


def test_ci95_of_binary_trials_by_method():
    result = CandidateResult.from_trials([_trial(1, True), _trial(2, False), _trial(3, True)], wall_s=0.0)
    assert result.ci95() == result.ci95("wilson") == metrics.wilson_interval(2, 3)
    assert result.ci95("normal") == metrics.mean_interval([1.0, 0.0, 1.0])


def test_summary_interval_follows_the_method():
    result = _openings([0.35, 0.31, 0.12, 0.33])
    summary = result.summary(ci="bootstrap")
    assert summary["ci95"] == list(metrics.bootstrap_interval([0.35, 0.31, 0.12, 0.33]))
    assert summary["score"] == pytest.approx(0.2775) and summary["success_rate"] == pytest.approx(0.75)
    assert result.summary()["ci95"] == list(metrics.mean_interval([0.35, 0.31, 0.12, 0.33]))
