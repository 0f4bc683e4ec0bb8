"""A ManiSkill task's settings mistyped or a user's module that misbehaves: one ``error:`` line (exit code 2)
naming the setting (``task.session.KEY``) and the fix, never a ManiSkill traceback or a silent wrong score."""

from __future__ import annotations

import math
import sys
import textwrap

import pytest

from tests.cli._apps import app, error_line

USER_MODULE = '''
import sys

NOT_A_FUNCTION = 3


def as_list(env, swap):
    return [("cube_half_size", 0.02)]


def nan(env, swap):
    return {"cube_half_size": env.cube_half_size * float("nan")}
'''


@pytest.fixture
def user_pkg(tmp_path, monkeypatch):
    """``userpkg.refreshes`` (refresh functions that misbehave) and ``userpkg.exits`` (``sys.exit(3)`` on import),
    importable here and in the workers."""
    pkg = tmp_path / "pkg" / "userpkg"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "refreshes.py").write_text(textwrap.dedent(USER_MODULE))
    (pkg / "exits.py").write_text("import sys\nsys.exit(3)\n")
    monkeypatch.syspath_prepend(str(pkg.parent))
    monkeypatch.setenv("PYTHONPATH", f"{pkg.parent}:{':'.join(sys.path)}")
    yield pkg
    for name in [m for m in sys.modules if m.startswith("userpkg")]:
        del sys.modules[name]


@pytest.mark.sim
@pytest.mark.parametrize(("override", "words"), [
    ("task.session.obs_mode=statee", ["task.session.obs_mode=statee is not a ManiSkill observation mode",
                                      "did you mean state or state_dict?"]),
    ("task.session.control_mode=pd_ee_delta_poss", ["task.session.control_mode=pd_ee_delta_poss is not a control mode "
                                                    "of PushCube-v1's robot (did you mean pd_ee_delta_pos", "its modes: "]),
    ("+task.session.env_kwargs.robot_uids=panda_typo", ["robot_uids=panda_typo is not a registered ManiSkill robot",
                                                        "panda"]),
    ("task.session.failure_flags=is_grasped", ["task.session.failure_flags=is_grasped: give a list",
                                               "task.session.failure_flags=[is_grasped]"]),
    ("task.session.env_module=userpkg.exits", ["task.session.env_module=userpkg.exits called sys.exit(3) while being "
                                               "imported"]),
    ("task.session.refresh=userpkg.refreshes.NOT_A_FUNCTION", ["task.session.refresh=userpkg.refreshes.NOT_A_FUNCTION "
                                                               "is not a function (it is 3)"]),
])
def test_a_mistyped_maniskill_setting_is_one_line_naming_it(user_pkg, tmp_path, capsys, override, words):
    out = tmp_path / "out"
    code, _, err = app("evaluate", "task=push_cube", "policy=push_cube_expert", "budget.trials=1", override,
                       f"hydra.run.dir={out}", capsys=capsys)
    line = error_line(err)
    assert code == 2 and all(w in line for w in words), line
    assert not out.exists()


def test_a_refresh_must_return_finite_values_of_the_envs_attributes():
    from grt.tasks.maniskill.swap import RefreshError, refreshed

    class Env:
        cube_half_size = 0.02

    def as_list(env, swap):
        return [("cube_half_size", 0.02)]

    with pytest.raises(RefreshError, match=r"as_list returned a list; it must return a dict \{attribute: value\}"):
        refreshed(as_list, Env(), None)
    with pytest.raises(RefreshError, match=r"returned cube_half_size=nan \(not finite\)"):
        refreshed(lambda env, swap: {"cube_half_size": math.nan}, Env(), None)
    with pytest.raises(RefreshError, match=r"the key 'cube_size', which is no attribute of Env"):
        refreshed(lambda env, swap: {"cube_size": 0.02}, Env(), None)
    assert refreshed(lambda env, swap: {"cube_half_size": 0.03}, Env(), None) == {"cube_half_size": 0.03}


@pytest.mark.sim
@pytest.mark.slow
def test_a_refresh_returning_nan_stops_the_evaluation_naming_it(user_pkg, tmp_path, capsys):
    """Every trial was a ``timeout`` and ``grt.evaluate`` printed 0.000 with exit code 0."""
    code, _, err = app("evaluate", "task=push_cube", "policy=push_cube_expert", "budget.trials=1", "budget.workers=1",
                       "task.session.refresh=userpkg.refreshes.nan", f"hydra.run.dir={tmp_path / 'out'}", capsys=capsys)
    line = error_line("\n".join(row for row in err.splitlines() if not row.startswith("trials:")))  # no progress
    assert code == 2 and "ended in sim_error" in line and "RefreshError: task.session.refresh=userpkg.refreshes.nan " \
                                                           "returned cube_half_size=nan (not finite)" in line, line


@pytest.mark.sim
def test_a_refresh_is_checked_by_the_public_helper_against_the_stock_env_and_a_scaled_candidate(tmp_path):
    """The stale-nominal check pointed at a GRT test file; ``check_refresh`` takes a task YAML of the user's."""
    from pathlib import Path

    from grt.tasks.maniskill.refresh_check import check_refresh

    yaml = tmp_path / "mine.yaml"
    yaml.write_text((Path(__file__).resolve().parents[2] / "conf" / "task" / "push_cube.yaml").read_text())
    (row,) = check_refresh(str(yaml), scale=1.3)
    assert row["attribute"] == "cube_half_size" and row["nominal_error_m"] < 1e-6
    assert row["stock"] == pytest.approx([0.02]) and row["scaled"] == pytest.approx([0.026], abs=1e-6)
    stale = (tmp_path / "stale.py")
    stale.write_text("def stock(env, swap):\n    return {'cube_half_size': 0.02}\n")
    sys.path.insert(0, str(tmp_path))
    try:
        text = yaml.read_text().replace("refresh: grt.tasks.maniskill.refresh.push_cube", "refresh: stale.stock")
        yaml.write_text(text)
        (row,) = check_refresh(str(yaml), scale=1.3)
        assert row["scaled"] == pytest.approx([0.02])  # a refresh that ignores the candidate: caught
    finally:
        sys.path.remove(str(tmp_path))


DRIVERS = '''
from grt.policies.base import EnvDriverPolicy


class Finishes(EnvDriverPolicy):
    """A plan that runs to its end (three steps of nothing) without success."""

    def solve(self, env, seed):
        env.reset(seed=seed)
        for _ in range(3):
            env.step(env.action_space.sample() * 0)
        return {"planned": True, "status": "ok"}


class NoPlan(EnvDriverPolicy):
    def solve(self, env, seed):
        env.reset(seed=seed)
        print("IK Failed! Cannot find valid solution.")
        return {"planned": False, "status": "IK Failed! Cannot find valid solution."}


class Forever(EnvDriverPolicy):
    def solve(self, env, seed):
        env.reset(seed=seed)
        while True:
            env.step(env.action_space.sample() * 0)
'''


@pytest.mark.sim
@pytest.mark.slow
@pytest.mark.parametrize(("driver", "mode", "note"), [
    ("Finishes", "plan_ended", None), ("NoPlan", "no_plan", "IK Failed! Cannot find valid solution."),
    ("Forever", "timeout", "stopped after driver_step_limit=5 steps")])
def test_a_driven_trial_is_labelled_by_how_its_plan_ended_and_keeps_its_message(user_pkg, tmp_path, capsys, driver,
                                                                                mode, note):
    """A task without failure flags labelled every failure of a motion planner ``timeout``, though the planner
    had finished, and its failure message was in no output file."""
    import json

    (user_pkg / "drivers.py").write_text(DRIVERS)
    out = tmp_path / "out"
    code, _, err = app("evaluate", "task=push_cube", "~policy", f"+policy={{_target_:userpkg.drivers.{driver}}}",
                       "budget.trials=1", "budget.workers=1", "+task.session.driver_step_limit=5",
                       f"hydra.run.dir={out}", capsys=capsys)
    assert code == 0, err[-3000:]
    (trial,) = json.loads((out / "evaluation.json").read_text())["trials"]
    assert trial["mode"] == mode and trial["info"].get("note") == note, trial
