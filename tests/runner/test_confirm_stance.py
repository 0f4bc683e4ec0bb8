"""A CrashShape whose object cannot stand: the confirmation counts the episodes where the object was still
falling or lay on its side when the policy looked (the grasp task's ``tilt_deg`` and ``spin_dps``), and the
console says so beside the confirmed drop (a deformed bottle that falls over fails every grasp policy alike)."""

from __future__ import annotations

import json

from grt.confirm import SPIN_DPS, TILT_DEG, unsettled
from grt.outputs import print_summary


def test_unsettled_counts_falling_and_lying_episodes_only_where_recorded():
    trials = [{"tilt_deg": 0.7, "spin_dps": 5.0}, {"tilt_deg": 31.0, "spin_dps": 254.0},
              {"tilt_deg": TILT_DEG + 1, "spin_dps": 0.0}, {"tilt_deg": 20.0, "spin_dps": SPIN_DPS - 1},
              {"seed": 4}]  # a trial that recorded no stance is not counted either way
    assert unsettled(trials) == {"unsettled": 2, "stance_trials": 4}
    assert unsettled([{"seed": 1, "score": 0.0}]) == {}  # other tasks, older journals: nothing said


def test_the_console_says_when_a_confirmed_drop_is_the_shapes_stability(toy_run, tmp_path, capsys):
    summary = json.loads((toy_run / "summary.json").read_text())
    conf = summary["confirm"]
    conf.update(unsettled=0, stance_trials=4)
    assert len(conf["shapes"]) >= 2
    conf["shapes"][0].update(unsettled=4, stance_trials=4, confirmed=True)
    conf["shapes"][1].update(unsettled=1, stance_trials=4, confirmed=True)
    for shape in conf["shapes"][2:]:  # unsettled, but its drop is not confirmed: nothing to explain
        shape.update(unsettled=4, stance_trials=4, confirmed=False)
    print_summary(summary, tmp_path)
    out = " ".join(capsys.readouterr().out.split())
    assert "rank 1:" in out and "in 4/4 episodes the object was still moving or had fallen over when the policy " \
        "looked (nominal 0/4)" in out
    assert out.count("still moving") == 1  # not a shape that moved in 1 of 4, nor an unconfirmed one


def test_a_real_grasp_trial_records_the_stance(grasp_evaluation):
    """The stance the confirmation counts comes from each grasp trial's info (grt.evaluate writes it)."""
    out, _ = grasp_evaluation
    trials = json.loads((out / "evaluation.json").read_text())["trials"]
    assert trials and all(0.0 <= t["info"]["tilt_deg"] < 5.0 and t["info"]["spin_dps"] >= 0.0 for t in trials)
