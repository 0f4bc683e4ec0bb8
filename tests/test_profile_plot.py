"""profile.png is drawn from any profile.json, including an interval that a rounding error leaves a hair inside
its score (the profile of a run ended in a traceback after all its episodes were simulated)."""

from __future__ import annotations

from grt.profile.plot import plot_profile

LEVEL = {"size_mm": 4.0, "score": 1.0, "ci95": [0.6096569663469354, 0.9999999999999999], "confirmed": False}


def _profile() -> dict:
    return {"task": "grasp", "object": "bottle", "policy": "antipodal", "s0": 1.0, "s0_ci95": [0.89, 1.0],
            "threshold": 0.9, "crash_margin": 0.1, "shapes": 3, "trials": 12,
            "random": [{"size_mm": 4.0, "score": 1.0, "ci95": [0.9, 0.9999999999999999], "shapes": [{"score": 1.0}]}],
            "adversarial": [{"rank": 2, "levels": [LEVEL, {**LEVEL, "size_mm": 8.0, "score": 0.0,
                                                           "ci95": [1e-17, 0.39], "confirmed": True}]}],
            "margins": {"random_mm": 8.0, "random_beyond": False, "adversarial_mm": 8.0}}


def test_a_score_a_rounding_error_outside_its_interval_is_drawn(tmp_path):
    out = plot_profile(_profile(), tmp_path / "profile.png")
    assert out.stat().st_size > 10_000
