"""Early stopping on validation episodes: what is kept as val_best.pt and when training stops."""

from __future__ import annotations

import pytest

from grt.rl.train import _Validation


def _run(tmp_path, scores, **kw):
    val = _Validation(lambda path: scores.pop(0), tmp_path, **kw)
    kept, stops = [], []
    for it in range(len(scores)):
        ckpt = tmp_path / "val_current.pt"
        ckpt.write_text(f"iteration {it}")
        stops.append(val.check(it, ckpt))
        kept.append((tmp_path / "val_best.pt").read_text())
    return val, kept, stops


def test_the_best_is_kept_and_training_stops_after_patience(tmp_path):
    val, kept, stops = _run(tmp_path, [0.2, 0.5, 0.4, 0.45, 0.3], patience=3, perfect=None)
    assert kept == ["iteration 0", "iteration 1", "iteration 1", "iteration 1", "iteration 1"]
    assert stops == [False, False, False, False, True]
    assert val.best == pytest.approx(0.5)


def test_a_perfect_binary_score_stops_at_once_but_a_continuous_one_has_no_perfect_value(tmp_path):
    _, _, stops = _run(tmp_path, [0.5, 1.0], patience=3, perfect=1.0)
    assert stops == [False, True]
    (tmp_path / "continuous").mkdir()
    _, _, stops = _run(tmp_path / "continuous", [0.5, 1.0], patience=3, perfect=None)
    assert stops == [False, False]


def test_a_tie_keeps_the_more_trained_policy_without_counting_as_a_gain(tmp_path):
    val, kept, stops = _run(tmp_path, [0.383, 0.382, 0.3825, 0.30, 0.37], patience=3, perfect=None, tie=0.002)
    assert kept == ["iteration 0", "iteration 1", "iteration 2", "iteration 2", "iteration 2"]
    assert stops == [False, False, False, True, True]
