"""Your own code and configs (issue 40): your config folder (``--config-dir``), your classes refused in one line
when they cannot be built, keys nothing reads, every group checked before anything is written, and
``grt.select task=``.

Most commands run in this process (:mod:`tests.cli._apps`): each is refused before any simulation, so a process
start would cost more than the check. The user's sweep runs as a user runs it: a ``python -m grt.run``
process started in the user's own folder, outside the repository.
"""

from __future__ import annotations

import copy
import inspect
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hydra.utils import get_object
from omegaconf import OmegaConf, open_dict

from grt.config import SettingError, check_added_keys, validate
from grt.errors import UserError
from grt.runfolder.resume import resume_overrides
from grt.targets import ClassError
from tests.cli._apps import ROOT, app, error_line, user_project
from tests.runner._toy_run import TOY
from tests.runner.conftest import compose_run

SMOKE = ["budget=smoke", "budget.trials=2", "object=can", *TOY]  # the can: a built-in without slivers, no remesh
SESSION = "tests.evaluators._toy_session"  # a real worker pool's cheap session (tests/evaluators/_toy_session.py)


@pytest.fixture(scope="module")
def project(tmp_path_factory) -> Path:
    return user_project(tmp_path_factory.mktemp("my_project"))


@pytest.fixture
def mine(project, monkeypatch):
    """The user's package importable here (what their PYTHONPATH does for a command)."""
    monkeypatch.syspath_prepend(str(project))
    return project


def _trace(line: str) -> str:
    """The traceback file a refusal names, read."""
    return Path(re.search(r"the whole traceback: (\S+)\)", line).group(1)).read_text()


# ------------------------------------------------------------------ your config folder (--config-dir), sweeps
def test_a_users_sweep_from_their_own_folder_with_their_configs_and_classes(project, tmp_path, capsys):
    """Outside the repository, the user's package on PYTHONPATH: their experiment, policy and selectors in a
    sweep. The sweep says its folder when it starts and ends; the job whose selector cannot be built fails
    (the sweep goes on), and the sweep says so on stderr and exits 1; grt.report lists it, and a job that
    never wrote summary.json as unfinished."""
    sweep = tmp_path / "sweep"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(project), str(ROOT)]), "WANDB_MODE": "disabled"}
    env.pop("HYDRA_FULL_ERROR", None)
    proc = subprocess.run([sys.executable, "-m", "grt.run", "--config-dir", "conf", "-m", "experiment=mine",
                           "selector=corners,broken", "+task.ci=wilson", f"hydra.sweep.dir={sweep}"],
                          cwd=project, env=env, capture_output=True, text=True, timeout=300)
    ok, failed = sweep / "0_planner_corners-topdm", sweep / "1_planner_broken-topdm"
    assert proc.returncode == 1, proc.stdout[-3000:] + proc.stderr[-3000:]
    lines = proc.stdout.strip().splitlines()
    assert lines[0] == f"sweep folder: {sweep}" and lines[-1].startswith(f"sweep folder: {sweep} (2 jobs; ")
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]  # (the bars are on stderr)
    assert "Traceback" not in proc.stderr and errors == [
        f"error: 1 of 2 jobs of the sweep failed: 1_planner_broken-topdm (error: {failed / 'error.txt'}); python -m "
        f"grt.report {sweep} lists them"], proc.stderr[-3000:]
    summary = json.loads((ok / "summary.json").read_text())
    assert summary["evaluations"] == 7 and summary["ci"] == "wilson"  # +task.ci: a key GRT reads, accepted
    assert json.loads((ok / "handles.json").read_text())["notes"]["selector"] == "corners"  # the user's class
    assert "_target_: mypkg.TablePlanner" in (ok / "run_config.yaml").read_text()
    assert "RuntimeError: no GPU for my selector" in (failed / "error.txt").read_text()
    # resume=JOB alone finds the user's config folder again (Hydra's record of the job's config sources)
    from grt.cli._common import recorded_config_dir

    assert recorded_config_dir(resume_overrides([f"resume={ok}"])) == str(project / "conf")
    code, out, _ = app("report", str(sweep), capsys=capsys)
    assert code == 0 and f"1 failed job(s) (see error.txt):\n- {failed}" in out
    (ok / "summary.json").unlink()  # a job killed before its end: its record and journal, no summary
    code, out, _ = app("report", str(sweep), capsys=capsys)
    assert code == 0 and "1 unfinished job(s) (no summary.json" in out and f"- {ok}" in out


def test_help_lists_the_users_options_beside_grts(project, capsys):
    code, out, _ = app("run", "--config-dir", str(project / "conf"), "--help", capsys=capsys)
    assert code == 0
    policy = next(line for line in out.splitlines() if line.startswith("policy: "))
    options = policy.removeprefix("policy: ").split("  (now: ")[0].split(", ")
    assert options == sorted(options) and {"antipodal", "broken", "planner", "remote"} <= set(options)
    assert "selector: all, broken, corners, heuristic, manual, vlm" in out
    experiment = next(line for line in out.splitlines() if line.startswith("experiment: "))
    assert experiment.startswith("experiment: mine, ") and "table1_drawer" in experiment
    code, _, err = app("run", "--config-dir", str(project / "nowhere"), "--help", capsys=capsys)
    assert code == 2 and "--config-dir: the config folder" in error_line(err) and "not found" in err


# ------------------------------------------------------------------ a class that cannot be built
GROUPS = ["policy", "task.session", "selector", "optimizer", "evaluator", "logger"]


@pytest.fixture(scope="module")
def composed():
    """The run's config (toy scoring), composed once; each case changes a copy."""
    return compose_run([*SMOKE, "+evaluator.bar_mm=1"])


def _with(cfg, key: str, value):
    cfg = copy.deepcopy(cfg)
    with open_dict(cfg):
        OmegaConf.update(cfg, key, value, force_add=True)
    return cfg


@pytest.mark.parametrize("group", GROUPS)
def test_every_groups_class_is_imported_and_its_arguments_checked_before_anything(group, composed, mine):
    """What every app's validate(cfg) refuses, for each group a user fills with a class."""
    with pytest.raises(ClassError, match=rf"{group}.*: Python cannot import the module 'nosuch'; make it importable: "
                                         "install your package .* or add the folder that holds it to PYTHONPATH"):
        validate(_with(composed, f"{group}._target_", "nosuch.things.Thing"))
    with pytest.raises(ClassError, match=r"mypkg \(.*mypkg/__init__.py\) has no 'CornerSelectr'; did you mean "
                                         r"mypkg.CornerSelector\?"):
        validate(_with(composed, f"{group}._target_", "mypkg.CornerSelectr"))
    target = get_object(str(OmegaConf.select(composed, f"{group}._target_")))
    if inspect.Parameter.VAR_KEYWORD in {p.kind for p in inspect.signature(target).parameters.values()}:
        return  # it takes any keyword (**kwargs): nothing to refuse
    with pytest.raises(ClassError, match=r"takes no argument 'bogus_key' \(it takes: "):
        validate(_with(composed, f"{group}.bogus_key", 1))


def test_a_misspelled_argument_names_the_close_one(mine, capsys, tmp_path):
    code, _, err = app("run", "--config-dir", str(mine / "conf"), *SMOKE, "selector=corners", "+selector.kk=3",
                       f"hydra.run.dir={tmp_path / 'run'}", capsys=capsys)
    assert code == 2 and error_line(err).startswith("error: selector=corners (mypkg.CornerSelector) takes no argument "
                                                    "'kk' (it takes: k); did you mean selector.k?")


def test_a_class_whose_constructor_raises_is_one_line_and_no_folder(mine, tmp_path, capsys):
    """grt.run, for the policy (built in the main process) and the selector (built before the record is saved)."""
    for choice, words in (("policy=broken", "policy=broken (mypkg.BrokenPolicy): building it raised ValueError: "
                           "weights file missing: /nowhere/weights.pt ("),
                          ("selector=broken", "selector=broken (mypkg.BrokenSelector): building it raised "
                           "RuntimeError: no GPU for my selector (")):
        out = tmp_path / choice.replace("=", "_")
        code, _, err = app("run", "--config-dir", str(mine / "conf"), *SMOKE, choice,
                           f"hydra.run.dir={out}", capsys=capsys)
        line = error_line(err)
        assert code == 2 and words in line and "second line" not in line, line
        assert "Traceback (most recent call last)" in _trace(line)  # the whole traceback, in the named file
        assert line.endswith(f"(nothing was saved and the new folder {out} was removed)") and not out.exists()


def test_a_session_that_raises_in_the_workers_is_refused_before_the_record_is_saved(tmp_path, capsys, monkeypatch):
    """The real worker pool: its workers build the task's session as they start, before run_config.yaml."""
    monkeypatch.syspath_prepend(str(ROOT / "tests" / "evaluators"))  # spawned workers get this process's path
    out = tmp_path / "run"
    code, _, err = app("run", "budget=smoke", "object=can", "budget.workers=1", "~task.session",
                       "+task.session={_target_:_toy_session.ToySession,fail_build:true}", "~policy",
                       "+policy={_target_:_toy_session.ToyPolicy}", f"hydra.run.dir={out}", capsys=capsys)
    line = error_line(err)
    assert code == 2 and "task.session (_toy_session.ToySession) could not be built in an evaluator worker: " \
                         "RuntimeError: toy session refuses to build" in line, line
    assert "Traceback" in _trace(line) and not out.exists()


@pytest.mark.parametrize(("name", "args", "words"), [
    ("evaluate", [*TOY, "policy._target_=mypkg.policies.Mine"], "policy._target_=mypkg.policies.Mine: Python "
     "cannot import the module 'mypkg.policies' (mypkg ("),
    ("select", ["object=can", "selector=broken"], "selector=broken (mypkg.BrokenSelector): building it raised "
     "RuntimeError: no GPU for my selector"),
    ("serve", [TOY[0], "policy=broken"], "policy=broken (mypkg.BrokenPolicy): building it raised ValueError"),
    ("train", [TOY[0], "train.bc.expert._target_=mypkg.NoSuchExpert"], "train.bc.expert._target_=mypkg.NoSuchExpert: "
     "mypkg ("),
    ("blueteam", ["run=/nowhere", "+evaluator.bogus_key=1"], "evaluator=sim (grt.evaluators.sim.SimEvaluator) "
     "takes no argument 'bogus_key'"),
    ("serve", [TOY[0], "+serve.prot=1"], "did you mean serve.port?"),
])
def test_every_app_refuses_a_class_it_cannot_build_in_one_line_and_leaves_no_folder(name, args, words, mine, tmp_path,
                                                                                  capsys):
    out = tmp_path / "out"
    code, _, err = app(name, "--config-dir", str(mine / "conf"), *args, f"hydra.run.dir={out}", capsys=capsys)
    line = error_line(err)
    assert code == 2 and words in line, line
    assert not out.exists(), sorted(p.name for p in out.iterdir())


# ------------------------------------------------------------------ keys nothing reads, values checked first
@pytest.mark.parametrize(("args", "words"), [
    (["+deformer.lamda=2"], "+deformer.lamda: nothing reads deformer.lamda (added with '+', it would be stored and "
                            "never used); deformer's keys are lam, max_volume_change, method, radius, validity; did "
                            "you mean deformer.lam?"),
    (["+foo=1"], "+foo: nothing reads foo (added with '+', it would be stored and never used); grt.run's keys are "),
    (["deformer.lamda=2"], "deformer.lamda is not a setting of deformer (its keys are lam, max_volume_change, "
                           "method, radius, validity); did you mean deformer.lam?"),  # without '+': Hydra's refusal
    (["optimizer.sigmma=0.1"], "optimizer.sigmma is not a setting of optimizer (its keys are elite_frac, gamma, mu0, "
                               "population, seed, sigma); did you mean optimizer.sigma"),  # TOPDM's
    (["deformer.method=foo"], "deformer.method='foo': use one of smooth, exact, apap"),
    (["selector.k=0"], "selector=heuristic (grt.selectors.heuristic.HeuristicSelector): building it raised "
                       "ValueError: k must be >= 1, got 0"),
])
def test_keys_nothing_reads_and_bad_values_are_refused_before_the_folder_is_saved(args, words, tmp_path, capsys):
    out = tmp_path / "run"
    code, _, err = app("run", *SMOKE, *args, f"hydra.run.dir={out}", capsys=capsys)
    line = error_line(err)
    assert code == 2 and words in line, line
    assert not out.exists()


@pytest.mark.parametrize(("key", "value", "words"), [
    ("deformer.radius", 2, "deformer.radius=2: give a number in (0, 1]"),
    ("deformer.lam", 0, "deformer.lam=0: give a number > 0"),
    ("deformer.validity", "maybe", "deformer.validity='maybe': give true"),
    ("deformer.max_volume_change", -1, "deformer.max_volume_change=-1: give a number > 0"),
    ("report.videos", -1, "report.videos=-1: give an integer >= 0"),
    ("mesh.remesh", "maybe", "mesh.remesh='maybe': use one of auto, on, off"),
    ("task.ci", "student", "task.ci='student': use one of"),
])
def test_every_section_is_checked_by_validate(key, value, words, composed):
    with pytest.raises(UserError, match=re.escape(words)):
        validate(_with(composed, key, value))


def test_keys_a_class_or_grt_reads_are_accepted(composed):
    """+task.ci (read when given), an argument the class takes, ~key then +key again: nothing refused."""
    added = ["+task.ci=wilson", "+evaluator.bar_mm=4", "~task.nominal_floor", "+task.nominal_floor=0.0",
             "+experiment=table1_grasp"]
    cfg = compose_run([*SMOKE, *added[:-1]])
    check_added_keys(cfg, added, "grt.run", {"experiment", "policy", "task"})
    for added, words in (("+task.cii=wilson", "did you mean task.ci?"),
                         ("+mesh.remesh_mode=on", "mesh's keys are components, edge_length, fidelity_mm, remesh, "
                                                  "volume_tol")):
        with pytest.raises(SettingError, match=re.escape(words)):
            check_added_keys(_with(composed, added[1:].split("=")[0], "x"), [added])


# ------------------------------------------------------------------ grt.select takes task=
def test_select_takes_the_task_and_its_manual_regions(tmp_path, capsys):
    out = tmp_path / "sel"
    code, stdout, err = app("select", "task=insertion", "selector=manual", f"hydra.run.dir={out}", capsys=capsys)
    assert code == 0, err
    record = json.loads((out / "handles.json").read_text())
    assert record["object"] == "usb_plug" and record["task_name"] == "insertion"  # the task's plug
    assert record["task"].startswith("A Franka Panda holds a plug") and len(record["handles"]) == 8  # task.manual
    assert "ManualSelector on 'usb_plug' for task=insertion:" in stdout
    code, _, err = app("select", "+task=insertion", f"hydra.run.dir={tmp_path / 'x'}", capsys=capsys)
    assert code == 2 and "task is a config group this command already chooses: give task=OPTION" in error_line(err)
