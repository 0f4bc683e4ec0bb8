"""ManiSkill's motion-planning solutions as a policy (grt/policies/motion_planner.py): through grt.evaluate
they run in simulator workers on numpy 1.26 (``make motionplanning``), GRT's main process on numpy 2; without
the set-up, on a task in another control mode or an env without a solution, one line before any simulation.

The run needs the set-up's folder (``make test`` makes it); without it that test is skipped and says so.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from grt.policies.motion_planner import (
    MotionPlannerPolicy,
    MotionPlanningSetupError,
    NoSolutionError,
    has_solution,
    solution_module,
)
from tests.runner.conftest import refused_by_evaluate

ROOT = Path(__file__).resolve().parents[2]
MP_DIR = ROOT / ".motionplanning"
needs_setup = pytest.mark.skipif(not (MP_DIR / "numpy").is_dir(),
                                 reason=f"no numpy 1.26 in {MP_DIR}: run `make motionplanning` (make test does)")


def _evaluate(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.evaluate", "task=pick_cube", "policy=motion_planner", *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=600, env={**os.environ, **(env or {})})


class _NoSimulation:
    """An evaluator that must not be asked for anything: the swap check is cached."""

    runs_stock = True

    def evaluate(self, meshes, seeds):
        raise AssertionError("the cached swap check simulated again")


@needs_setup
@pytest.mark.sim
def test_the_planner_solves_pick_cube_in_its_own_numpy_workers(tmp_path):
    """... and the box task's copy is checked against the stock env on the same seeds (the nominal's trials once
    more), printed, recorded and cached, so the next command with the same task, policy, object and seeds does
    not pay it again."""
    args = ["task.session.control_mode=pd_joint_pos", "budget.trials=2", "budget.workers=1"]
    proc = _evaluate(*args, f"hydra.run.dir={tmp_path / 'out'}", env={"GRT_CACHE_DIR": str(tmp_path / "cache")})
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    saved = json.loads((tmp_path / "out" / "evaluation.json").read_text())
    assert saved["outcomes"] == {"success": 2}, saved["outcomes"]  # ManiSkill's solution: 10/10 on the stock cube
    assert all(t["info"]["steps"] > 50 for t in saved["trials"])  # the planner drove the env (plans of ~100 steps)
    check = saved["swap_check"]
    assert check["passed"] and not check["cached"] and check["agreement"] == 1.0 and check["seeds"] == saved["seeds"]
    assert check["swap"]["modes"] == [t["mode"] for t in saved["trials"]]
    assert ("swap check: stock 1.000 vs nominal swap 1.000 success on the same 2 seeds, agreement 1.000 (min 0.75), "
            "McNemar p = 1: passed") in proc.stdout

    from grt.agreement import SwapCheckSettings
    from grt.cli.evaluate import _swap_check
    from grt.geometry.mesh import load_mesh
    from grt.geometry.prepare import MeshSettings
    from grt.tasks import task_object
    from tests.runner.conftest import compose_run

    cfg = compose_run(["task=pick_cube", "policy=motion_planner", *args, f"paths.cache_dir={tmp_path / 'cache'}"],
                      config_name="evaluate")  # the command's config, as it loads the cube
    mesh = load_mesh(task_object(cfg.task, "actor", cfg.paths.cache_dir), settings=MeshSettings.from_config(cfg.mesh))
    again, result = _swap_check(cfg, mesh, saved["seeds"], _NoSimulation(), SwapCheckSettings())
    assert again["cached"] and again["passed"] and result is None


def test_without_the_setup_the_planner_is_one_line_naming_it(tmp_path, capsys):
    code, err = refused_by_evaluate(["task=pick_cube", "policy=motion_planner", "task.session.control_mode=pd_joint_pos",
                                     f"paths.motionplanning={tmp_path / 'missing'}"], tmp_path / "out", capsys)
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == 2 and "Traceback" not in err and len(errors) == 1, err
    assert "`python -m grt.setup motionplanning`" in errors[0] and "numpy 2" in errors[0]
    assert not (tmp_path / "out" / "evaluation.json").exists()


@needs_setup
def test_another_control_mode_is_refused_before_the_object_is_prepared(tmp_path, capsys):
    """The control mode was checked when the policy was built, after the actor's mesh (seconds to a minute)."""
    cache = tmp_path / "cache"
    code, err = refused_by_evaluate(["task=pick_cube", "policy=motion_planner", f"paths.cache_dir={cache}"],
                                    tmp_path / "out", capsys)
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert code == 2 and len(errors) == 1 and "add task.session.control_mode=pd_joint_pos" in errors[0], err
    assert not list(cache.rglob("*.obj")) and "mesh" not in err.replace(errors[0], ""), err


@needs_setup
def test_another_control_mode_or_an_env_without_a_solution_is_refused():
    with pytest.raises(NoSolutionError, match="task.session.control_mode=pd_joint_pos"):
        MotionPlannerPolicy(worker_path=str(MP_DIR), env_id="PickCube-v1", control_mode="pd_ee_delta_pos")
    with pytest.raises(NoSolutionError, match=r"no motion-planning solution for PushT-v1 \(it has: .*PickCube-v1"):
        MotionPlannerPolicy(worker_path=str(MP_DIR), env_id="PushT-v1")
    with pytest.raises(MotionPlanningSetupError, match="names no worker_path"):
        MotionPlannerPolicy()
    MotionPlannerPolicy(worker_path=str(MP_DIR), env_id="PegInsertionSide-v1", control_mode="pd_joint_pos")
    assert solution_module("PegInsertionSide-v1").endswith("solutions.peg_insertion_side")
    assert solution_module("DrawSVG-v1").endswith("solutions.draw_svg") and has_solution("DrawSVG-v1")
    assert "mplib" not in sys.modules  # nothing above imported the planner into this (numpy 2) process
