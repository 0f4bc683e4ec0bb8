"""Metrics against hand-computed examples of the appendix definitions; the journal's crash safety."""

from __future__ import annotations

import json
import math

import pytest

from grt import metrics
from grt.journal import Journal, JournalError


def test_metrics_hand_computed():
    # S0 = 0.8; iteration bests 0.6, 0.6, 0.3, 0.4(->0.3) => C = 0, .25, .25, .625, .625
    s0, its = 0.8, [[0.7, 0.6], [0.9, 0.65], [0.3, 0.8], [0.4, 0.5]]
    curve = metrics.degradation_curve(s0, its)
    assert curve.tolist() == pytest.approx([0, 0.25, 0.25, 0.625, 0.625])
    assert metrics.final_drop(s0, its) == pytest.approx(0.625)
    assert metrics.auc(curve) == pytest.approx(0.125 + 0.25 + 0.4375 + 0.625)
    assert metrics.iter_at_50(curve) == (3, True)


def test_iter_at_50_not_reached_reports_T():
    curve = metrics.degradation_curve(1.0, [[0.9], [0.8], [0.7]])
    assert metrics.iter_at_50(curve) == (3, False)
    s = metrics.summarize(1.0, [[0.9], [0.8], [0.7]])
    assert s["reached_50"] is False and s["iter_at_50"] == 3 and s["final_drop"] == pytest.approx(0.3)


def test_zero_nominal_score_is_nan_not_crash():
    s = metrics.summarize(0.0, [[0.0]])
    assert math.isnan(s["final_drop"]) and s["curve"] == [None, None]


def test_delta_complexity_median_of_ten_worst():
    cands = [(i / 20, 2.0 + i) for i in range(20)]  # the ten lowest scores have entropy 2..11
    assert metrics.delta_complexity(1.0, cands) == pytest.approx(5.5)


def test_wilson_interval():
    lo, hi = metrics.wilson_interval(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-3) and hi == pytest.approx(0.9433, abs=1e-3)
    assert metrics.wilson_interval(0, 8)[0] == 0.0


def test_journal_append_reload_and_truncated_tail(tmp_path):
    path = tmp_path / "journal.jsonl"
    j = Journal(path)
    j.append({"iteration": 0, "candidate": 0, "score": 0.9})
    j.append({"iteration": 1, "candidate": 0, "score": 0.5})
    with open(path, "a") as f:  # a write killed half-way
        f.write('{"iteration": 1, "candidate": 1, "sco')
    j2 = Journal(path)
    assert j2.recovered_truncated_line and len(j2) == 2
    assert j2.get(1, 0)["score"] == 0.5 and j2.get(1, 1) is None
    j2.append({"iteration": 1, "candidate": 1, "score": 0.4})
    lines = path.read_text().splitlines()
    assert [json.loads(x)["candidate"] for x in lines] == [0, 0, 1]


def test_journal_corrupt_middle_line_is_a_clear_error(tmp_path):
    path = tmp_path / "journal.jsonl"
    path.write_text('{"iteration": 0, "candidate": 0, "score": 1}\nGARBAGE\n{"iteration": 1, "candidate": 0, "score": 1}\n')
    with pytest.raises(JournalError, match="line 2"):
        Journal(path)
    path.write_text('{"iteration": 0}\n')
    with pytest.raises(JournalError, match="lacks"):
        Journal(path)


def test_unscorable_candidates_are_skipped():
    curve = metrics.degradation_curve(1.0, [[float("nan"), 0.8], [float("nan")]])
    assert curve.tolist() == pytest.approx([0, 0.2, 0.2])
    assert metrics.delta_complexity(1.0, [(float("nan"), 9.0), (0.5, 2.0)]) == pytest.approx(1.0)


def test_journal_keeps_continuous_per_trial_scores_exactly(tmp_path):
    """A drawer task journals openings in meters per trial; a resume must replay the very same floats."""
    trials = [{"seed": 7, "score": 0.1 + 0.2, "success": True, "mode": "success"},
              {"seed": 8, "score": 1.234567890123e-5, "success": False, "mode": "jammed"},
              {"seed": 9, "score": 0.0, "success": False, "mode": "sim_error"}]
    rec = {"iteration": 1, "candidate": 0, "score": (0.1 + 0.2 + 1.234567890123e-5) / 2,
           "ci95": [float("nan"), float("nan")], "trials": trials}
    Journal(tmp_path / "journal.jsonl").append(rec)
    back = Journal(tmp_path / "journal.jsonl").get(1, 0)
    assert [t["score"] for t in back["trials"]] == [t["score"] for t in trials]  # bit for bit
    assert back["score"] == rec["score"] and all(math.isnan(x) for x in back["ci95"])
