"""The drawer through the CLIs: a continuous-score smoke red-team run, evaluation output, bad input."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from grt.runner import run
from tests.runner.conftest import compose_run, refused_by_evaluate

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.sim
@pytest.mark.slow
def test_smoke_red_team_run_on_the_drawer_has_continuous_scores(tmp_path):
    cfg = compose_run(["task=drawer", "policy=drawer_expert", "selector=manual", "budget=smoke",
                       "budget.trials=2", f"paths.output_dir={tmp_path}"])
    summary = run(cfg)
    assert 0.38 <= summary["s0"] <= 0.395  # the expert opens the nominal drawer fully: S0 in meters
    assert summary["score_name"] == "opening" and summary["score_unit"] == "m"
    assert summary["evaluations"] == 1 + cfg.budget.population * cfg.budget.iterations
    handles = json.loads((tmp_path / "handles.json").read_text())
    assert len(handles["handles"]) == 8  # task.manual: 8 handles on the grip, the feet anchored
    records = [json.loads(line) for line in (tmp_path / "journal.jsonl").read_text().splitlines()]
    trial_scores = [t["score"] for r in records for t in r["trials"]]
    assert all(0.0 <= s <= 0.395 for s in trial_scores)
    assert any(0.0 < s < 0.38 for s in trial_scores) or min(r["score"] for r in records) < 0.38
    for r in records:  # the candidate's score is the mean opening of its trials, its CI a bootstrap one
        valid = [t["score"] for t in r["trials"] if t["mode"] != "sim_error"]
        assert r["score"] == pytest.approx(sum(valid) / len(valid))
        assert set(r["outcomes"]) <= {"success", "slipped", "partial_open", "missed_handle", "timeout",
                                      "sim_error"}
    drops = summary["curve"]
    assert drops[0] == 0.0 and summary["final_drop"] == pytest.approx(drops[-1])


def _cli(module: str, *args: str, timeout: float = 300):
    env = {**os.environ, "WANDB_MODE": "disabled", "HYDRA_FULL_ERROR": "0"}
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)


BAD_INPUT = [
    (["object=bottle"], "'bottle' is no built-in drawer handle"),
    (["object=bottle", "task.session.handle_object=drawer_handle"], "sticks out 225 mm"),
    (["object=drawer_pull", "task.session.grasp_point=[0,0.03]"], "three numbers"),
    (["policy=insertion_state"], "trained for task 'insertion'"),
]


@pytest.mark.parametrize("args, message", BAD_INPUT)
def test_bad_drawer_input_is_one_line_and_exit_2(args, message, tmp_path, capsys):
    code, err = refused_by_evaluate(["task=drawer", "policy=drawer_expert", *args, "budget.trials=1"], tmp_path,
                                    capsys)  # grt.evaluate's app, in process
    assert code == 2 and message in err and err.count("\n") == 1, err


def test_bad_drawer_input_through_the_command(tmp_path):
    args, message = BAD_INPUT[0]
    out = _cli("grt.evaluate", "task=drawer", "policy=drawer_expert", *args, "budget.trials=1",
               f"hydra.run.dir={tmp_path}")
    assert out.returncode == 2, out.stdout + out.stderr
    assert message in out.stderr and "Traceback" not in out.stderr, out.stderr


@pytest.mark.sim
def test_evaluate_prints_the_mean_opening(tmp_path):
    out = _cli("grt.evaluate", "task=drawer", "policy=drawer_expert", "budget.trials=2", "budget.workers=1",
               f"hydra.run.dir={tmp_path}")
    assert out.returncode == 0, out.stderr[-2000:]
    last = json.loads(out.stdout.strip().splitlines()[-1])
    assert last["score_name"] == "opening" and last["score_unit"] == "m" and last["ci"] == "bootstrap"
    assert 0.38 <= last["score"] <= 0.395
    assert "mean opening (m)" in out.stdout
