"""``python -m grt.train`` never trains over what the user has (issue 30, 1): a resume of a folder that is not
there is refused, and the trained policy goes into the package only when asked, over a shipped file only
with ``train.overwrite_shipped=true``; a refused command leaves no folder.

The CLI cases run in a scratch working folder (``PYTHONPATH`` points at the repository), so the new run
folder Hydra would make (``outputs/train/...``) would land there, where the test can see it.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from grt.errors import OutputError
from grt.rl.policy_training import SHIPPED, check_export

ROOT = Path(__file__).resolve().parents[2]
SHIPPED_FILE = ROOT / "grt" / "policies" / "checkpoints" / "insertion_state.pt"


def grt_train(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
           "WANDB_MODE": "disabled"}
    return subprocess.run([sys.executable, "-m", "grt.train", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300, env=env)


def one_error_line(res: subprocess.CompletedProcess) -> str:
    assert res.returncode == 2, res.stderr[-3000:]
    assert "Traceback" not in res.stdout + res.stderr, res.stderr[-3000:]
    errors = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith("error: "), res.stderr[-3000:]
    return errors[0]


def test_a_resume_of_a_missing_folder_is_refused(tmp_path):
    line = one_error_line(grt_train(f"resume={tmp_path / 'gone'}", cwd=tmp_path))
    assert f"resume={tmp_path / 'gone'}: no such folder" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no outputs/


def test_a_resume_of_a_missing_folder_is_refused_with_a_run_folder_given_too(tmp_path):
    """With ``hydra.run.dir`` the folder's resolver never sees ``resume=``: the command is checked before Hydra
    starts (and the app checks it again), so Hydra makes no folder."""
    line = one_error_line(grt_train(f"resume={tmp_path / 'gone'}", f"hydra.run.dir={tmp_path / 'here'}", cwd=tmp_path))
    assert "no such folder" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.slow  # ~13 s (the app imports torch); check_export's own test below is fast
def test_replacing_a_shipped_policy_needs_the_flag_and_is_checked_before_training(tmp_path):
    before = hashlib.sha256(SHIPPED_FILE.read_bytes()).hexdigest()
    line = one_error_line(grt_train(f"train.export={SHIPPED_FILE}", cwd=tmp_path))
    assert "would replace a policy shipped with GRT" in line and "train.overwrite_shipped=true" in line, line
    assert "was removed" in line, line
    assert hashlib.sha256(SHIPPED_FILE.read_bytes()).hexdigest() == before
    assert not (tmp_path / "outputs").exists()


@pytest.mark.parametrize("train", ["insertion_state", "insertion_pcd", "drawer_state"])
def test_no_training_exports_into_the_package_by_default(train):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="train_policy", overrides=[f"train={train}"])
    assert cfg.train.export is None and cfg.train.overwrite_shipped is False
    assert check_export({"export": cfg.train.export}) is None


def test_check_export(tmp_path):
    assert check_export({"export": str(tmp_path / "mine.pt")}) == tmp_path / "mine.pt"
    assert check_export({"export": str(SHIPPED / "new_policy.pt")}) == SHIPPED / "new_policy.pt"  # a new one
    assert check_export({"export": str(SHIPPED_FILE), "overwrite_shipped": True}) == SHIPPED_FILE
    with pytest.raises(OutputError, match="overwrite_shipped=true"):
        check_export({"export": str(SHIPPED_FILE)})
    with pytest.raises(OutputError, match="end the name with one of .pt"):
        check_export({"export": str(tmp_path / "mine.onnx")})
    with pytest.raises(OutputError, match="does not exist"):
        check_export({"export": str(tmp_path / "no" / "mine.pt")})


def test_a_train_config_whose_expert_is_another_tasks_is_one_line_before_any_simulation(tmp_path):
    """``train=insertion_state`` (warm start from the insertion servo: 6 actions) on ``task=push_cube`` (4):
    before, the worker processes died on a reshape and the command ended in a 100-line traceback."""
    line = one_error_line(grt_train("task=push_cube", "train=insertion_state", cwd=tmp_path))
    assert "train.bc.expert" in line and "ServoInsertionPolicy" in line and "takes 4 actions" in line, line
    assert "train.bc=null" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no outputs/


def test_a_task_whose_episodes_run_a_grasp_planner_is_not_trained_one_line(tmp_path):
    """``task=grasp`` (one planned grasp an episode, no per-step actions): before, the worker processes died
    on a missing ``reset`` and the command ended in a traceback."""
    line = one_error_line(grt_train("task=grasp", "train.bc=null", cwd=tmp_path))
    assert "task=grasp (GraspSession) runs a grasp planner" in line and "trains a closed-loop PPO policy" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == []
