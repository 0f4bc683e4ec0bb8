"""A user's own config files and settings that were tracebacks: each is one ``error:`` line (exit code 2) naming
the file or key and the fix, before anything is written (the apps run in this process: ``tests/cli/_apps.py``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli._apps import app, error_line

ROOT = Path(__file__).resolve().parents[2]
PUSH_CUBE = (ROOT / "conf" / "task" / "push_cube.yaml").read_text()


def _task(folder: Path, name: str, text: str) -> Path:
    (folder / "task").mkdir(parents=True, exist_ok=True)
    (folder / "task" / f"{name}.yaml").write_text(text.replace("name: push_cube", f"name: {name}"))
    return folder


@pytest.mark.parametrize(("name", "edit", "words"), [
    ("tabbed", lambda t: t.replace("\n  obs_mode:", "\n\tobs_mode:"),
     ["tabbed.yaml, line {obs_mode:}, column 1: YAML cannot read the config file (found a TAB character",
      "YAML indents with spaces only"]),
    ("broken", lambda t: t.replace("\nscore: success", "\nscore: [success"),
     ["broken.yaml, line {score:}, column 1: YAML cannot read the config file (expected ',' or ']'",
      "fix the YAML there"]),
    ("noenv", lambda t: t.replace("env_id: PushCube-v1\n", ""),
     ["task.session.env_id reads a setting the config does not have (task.session.env_id: ${..env_id})",
      "add env_id: to the task config (or give task.env_id=VALUE)"]),
    ("notarget", lambda t: t.replace("  _target_: grt.tasks.maniskill.session.ManiSkillSession\n", ""),
     ["task.session of task 'notarget' has no _target_", "_target_: grt.tasks.maniskill.session.ManiSkillSession"]),
])
@pytest.mark.parametrize("how", ["searchpath", "config-dir"])
def test_a_broken_task_yaml_of_the_users_is_one_line_and_leaves_nothing(tmp_path, capsys, name, edit, words, how):
    text = edit(PUSH_CUBE)
    conf = _task(tmp_path / "conf", name, text)
    lines = text.splitlines()  # where YAML stops: the TAB's line; the line after an unclosed [
    words = [w.replace("{obs_mode:}", str(next(i for i, t in enumerate(lines, 1) if "obs_mode:" in t)))
              .replace("{score:}", str(next(i for i, t in enumerate(lines, 1) if t.startswith("score:")) + 1))
             for w in words]
    where = [f"hydra.searchpath=[file://{conf}]"] if how == "searchpath" else ["--config-dir", str(conf)]
    out = tmp_path / "out"
    code, _, err = app("evaluate", *where, f"task={name}", "policy=push_cube_expert", f"hydra.run.dir={out}",
                       capsys=capsys)
    line = error_line(err)
    assert code == 2 and all(w in line for w in words), line
    assert not out.exists()


def test_a_mapping_given_where_the_yaml_holds_a_list_says_how_to_replace_it(capsys):
    code, _, err = app("evaluate", "task=pick_cube", "task.session.failure_flags={is_grasped: not_grasped}",
                       capsys=capsys)
    assert code == 2 and error_line(err) == (
        "error: task.session.failure_flags is a list in the config, and Hydra merges only the same kind into it; "
        "to give {is_grasped: not_grasped} instead, replace it: '~task.session.failure_flags' "
        "'+task.session.failure_flags={is_grasped: not_grasped}'")


@pytest.mark.parametrize(("overrides", "words"), [
    (["optimizer=nevergrad", "optimizer.mu0=nan"], ["optimizer.mu0=nan: the mean of the first candidates must be a finite"]),
    (["optimizer=topdm", "optimizer.mu0=inf"], ["optimizer.mu0=inf"]),
    (["optimizer=optuna_gp", "optimizer.bound=inf"], ["optimizer.bound a finite number > 0", "got 3, inf"]),
    (["optimizer=optuna_gp", "optimizer.n_startup=1.5"], ["optimizer.n_startup=1.5: the initial design's size is a whole"]),
])
def test_optimizer_values_are_refused_before_the_runs_record_is_saved(tmp_path, capsys, overrides, words):
    """``mu0=nan`` and ``bound=inf`` were tracebacks after ``run_config.yaml`` was saved (a folder that could only
    repeat the crash); ``n_startup=1.5`` ran as 1."""
    from tests.runner._toy_run import TOY

    out = tmp_path / "run"
    code, _, err = app("run", "budget=smoke", "object=can", *TOY, *overrides, f"hydra.run.dir={out}", capsys=capsys)
    line = error_line(err)
    assert code == 2 and all(w in line for w in words), line
    assert not out.exists()


def test_no_vulkan_device_is_one_line_with_the_fix_before_the_object_is_prepared(tmp_path):
    """Without a Vulkan driver every worker failed after the object was prepared (44 s), with no word of the fix."""
    (tmp_path / "none.json").write_text("{}")
    env = {**os.environ, "VK_ICD_FILENAMES": str(tmp_path / "none.json"), "VK_DRIVER_FILES": str(tmp_path / "none.json")}
    proc = subprocess.run([sys.executable, "-m", "grt.evaluate", "task=insertion", "budget.trials=1",
                           f"hydra.run.dir={tmp_path / 'out'}"], cwd=ROOT, capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 2, proc.stderr[-3000:]
    line = error_line(proc.stderr)
    assert line.startswith("error: no Vulkan device on this machine (") and "mesa-vulkan-drivers" in line, line
    assert "fidelity" not in proc.stdout and not (tmp_path / "out").exists()


def test_a_policy_of_another_kind_is_refused_before_the_object_is_prepared(tmp_path, capsys):
    code, out, err = app("evaluate", "task=insertion", "policy=contact_graspnet", f"hydra.run.dir={tmp_path / 'out'}",
                         capsys=capsys)
    assert code == 2 and "policy=contact_graspnet (ContactGraspNetPolicy) is a grasp planner" in error_line(err)
    assert "fidelity" not in out  # the mesh's preparation prints its fidelity figures: not reached


@pytest.mark.parametrize(("override", "words"), [
    ("evaluator.runtime_env=garbage", "evaluator.runtime_env='garbage': give a mapping (Ray's runtime environment"),
    ("evaluator.runtime_env={env_vars: x}", "evaluator.runtime_env.env_vars='x': give a mapping"),
])
def test_a_ray_runtime_env_that_is_no_mapping_is_one_line(tmp_path, capsys, override, words):
    """Was ``building it raised ValueError: dictionary update sequence element #0 has length 1``."""
    from tests.runner._toy_run import TOY

    code, _, err = app("evaluate", "evaluator=ray", override, "object=can", "budget.trials=1", TOY[0],
                       f"hydra.run.dir={tmp_path / 'out'}", capsys=capsys)
    assert code == 2 and words in error_line(err), err


def test_an_argument_the_users_yaml_leaves_out_is_given_with_a_plus(tmp_path, capsys, monkeypatch):
    """``policy.predictor.noise=0.1`` (an argument of the user's class its YAML does not set) was "not a setting of
    policy.predictor (its keys are depth, jitter)", with no word of '+'."""
    (tmp_path / "pkg" / "mypred").mkdir(parents=True)
    (tmp_path / "pkg" / "mypred" / "__init__.py").write_text(
        "class Predictor:\n    def __init__(self, depth=1, jitter=0.0, noise=0.0):\n        pass\n\n\n"
        "class Wrapper:\n    def __init__(self, predictor=None):\n        pass\n")
    (tmp_path / "conf" / "policy").mkdir(parents=True)
    (tmp_path / "conf" / "policy" / "mine.yaml").write_text(
        "_target_: mypred.Wrapper\npredictor:\n  _target_: mypred.Predictor\n  depth: 2\n  jitter: 0.1\n")
    monkeypatch.syspath_prepend(str(tmp_path / "pkg"))
    code, _, err = app("evaluate", "--config-dir", str(tmp_path / "conf"), "policy=mine", "policy.predictor.noise=0.1",
                       capsys=capsys)
    assert code == 2 and error_line(err) == ("error: policy.predictor.noise is an argument of mypred.Predictor that "
                                             "the config does not set; add it with '+': +policy.predictor.noise=VALUE")
    code, _, err = app("evaluate", "--config-dir", str(tmp_path / "conf"), "policy=mine", "policy.predictor.nois=0.1",
                       capsys=capsys)
    assert code == 2 and "policy.predictor.nois is not a setting of policy.predictor" in error_line(err)


def test_a_run_of_a_task_from_the_users_searchpath_resumes_from_its_folder_alone(tmp_path):
    """The printed resume command failed: "Could not find 'task/mygrasp'" (hydra.searchpath was not kept)."""
    from tests.cli.test_run_faults import _env, lines
    from tests.runner._toy_run import TOY

    conf = _task(tmp_path / "conf", "mygrasp", (ROOT / "conf" / "task" / "grasp.yaml").read_text()
                 .replace("name: grasp", "name: mygrasp"))
    run_dir = tmp_path / "run"
    env = {**_env(), "GRT_TEST_INTERRUPT_AT": "3"}
    proc = subprocess.run([sys.executable, "-m", "grt.run", f"hydra.searchpath=[file://{conf}]", "task=mygrasp",
                           "budget=smoke", "object=can", *TOY, f"hydra.run.dir={run_dir}"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 130, proc.stderr[-3000:]
    command = proc.stderr.strip().splitlines()[-1].split("continue this run with: ")[1]
    toy = {**_env(), "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    res = subprocess.run(["bash", "-c", command.replace("python", sys.executable, 1)], cwd=tmp_path, env=toy,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    assert lines(run_dir) == 7 and (run_dir / "summary.json").is_file()


def test_help_lists_the_tasks_of_the_users_searchpath(tmp_path, capsys):
    """``--help`` with ``hydra.searchpath=[file://MYDIR]`` left the user's own tasks out (``--config-dir`` had them)."""
    conf = _task(tmp_path / "conf", "mine", PUSH_CUBE)
    code, out, _ = app("run", f"hydra.searchpath=[file://{conf}]", "--help", capsys=capsys)
    line = next(line for line in out.splitlines() if line.startswith("task: "))
    assert code == 0 and "mine" in line.split("(now")[0].split(", "), line
