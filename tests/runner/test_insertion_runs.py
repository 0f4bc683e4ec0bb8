"""Insertion through the CLIs: a smoke red-team run with the learned policy, and bad input."""

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
def test_smoke_red_team_run_on_insertion(tmp_path):
    cfg = compose_run(["task=insertion", "policy=insertion_state", "selector=manual", "budget=smoke",
                       "budget.trials=3", f"paths.output_dir={tmp_path}"])
    summary = run(cfg)
    assert summary["s0"] == 1.0  # the shipped policy inserts the nominal plug
    assert summary["evaluations"] == 1 + cfg.budget.population * cfg.budget.iterations
    handles = json.loads((tmp_path / "handles.json").read_text())
    assert len(handles["handles"]) == 8  # task.manual: 8 handles on the grip, the head anchored
    rec = json.loads((tmp_path / "journal.jsonl").read_text().splitlines()[-1])
    assert set(rec["outcomes"]) <= {"success", "jammed", "misaligned", "dropped", "timeout", "sim_error"}


def _cli(module: str, *args: str, timeout: float = 300):
    env = {**os.environ, "WANDB_MODE": "disabled", "HYDRA_FULL_ERROR": "0"}
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)


BAD_INPUT = [
    (["task=insertion", "policy=insertion_state", "policy.checkpoint=/nonexistent/x.pt"], "does not exist"),
    (["task=grasp", "policy=insertion_state"], "is a closed-loop policy"),  # refused by kind, before its checkpoint
    (["task=drawer", "policy=insertion_state"], "trained for task 'insertion'"),
    (["task=insertion", "policy=insertion_pcd", "task.session.cloud_points=100"],
     "expects observation 'cloud' of shape (500, 3)"),
    (["task=insertion", "policy=insertion_state", "object=mug"], "'mug' is a built-in object of the grasp task"),
    # grt.objects lists 'plug': a grasp object lying on its side, not one of the insertion plugs (issue 40)
    (["task=insertion", "policy=insertion_state", "object=plug"], "insertion task's built-in plugs are round_peg, "
     "usb_plug"),
    (["task=insertion", "policy=insertion_state", "object=mug", "task.session.socket_object=usb_plug",
      "task.session.head_length=0.012", "task.session.grip_height=0.03"], "wide across the fingers"),
    (["task=insertion", "policy=insertion_state", "object=/tmp/nonexistent_plug.obj"], "mesh file not found"),
]


@pytest.mark.parametrize("args, message", BAD_INPUT)
def test_bad_insertion_input_is_one_line_and_exit_2(args, message, tmp_path, capsys):
    code, err = refused_by_evaluate([*args, "budget.trials=1"], tmp_path, capsys)  # grt.evaluate's app, in process
    assert code == 2 and message in err and err.count("\n") == 1, err


def test_bad_insertion_input_through_the_command(tmp_path):
    args, message = BAD_INPUT[0]
    out = _cli("grt.evaluate", *args, "budget.trials=1", f"hydra.run.dir={tmp_path}")
    assert out.returncode == 2, out.stdout + out.stderr
    assert message in out.stderr and "Traceback" not in out.stderr, out.stderr


def test_a_corrupt_checkpoint_is_refused_by_the_run(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"\x00garbage")
    out = _cli("grt.run", "task=insertion", "policy=insertion_state", f"policy.checkpoint={bad}",
               f"hydra.run.dir={tmp_path / 'run'}")
    assert out.returncode == 2 and "cannot be read" in out.stdout + out.stderr
    assert "Traceback" not in out.stdout + out.stderr
    assert not (tmp_path / "run" / "handles.json").exists()  # refused before any file
