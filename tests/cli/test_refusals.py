"""Bad input refused through the command-line apps in one line, exit code 2, no traceback, before any
simulation (issue 30, items 4, 8, 12, 13, 14): a policy of the wrong kind for the task, ``selector=manual``
without handles, a folder as the object, a path Hydra cannot parse unquoted, a population CMA-ES cannot use.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import trimesh

from grt.policies.base import GraspStepPolicy
from grt.tasks import PolicyKindError, check_policy_kind

ROOT = Path(__file__).resolve().parents[2]
GRASP = {"name": "grasp", "session": {"_target_": "grt.tasks.grasp.GraspSession"}}
INSERTION = {"name": "insertion", "session": {"_target_": "grt.tasks.insertion.InsertionSession"}}


def _app(name: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", f"grt.{name}", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout)


def _refusal(proc: subprocess.CompletedProcess) -> str:
    """The one line that refuses the command (``error: ...`` on stderr, or ``grt.run``'s logged error)."""
    text = proc.stdout + proc.stderr
    assert proc.returncode == 2, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    lines = [line for line in text.splitlines() if line.startswith("error:") or "][ERROR]" in line]
    assert len(lines) == 1, text[-3000:]
    return lines[0]


@pytest.mark.parametrize(("app", "args", "words"), [
    ("evaluate", ["task=insertion", "policy=contact_graspnet"],  # the reported case: weights never loaded
     ["policy=contact_graspnet", "ContactGraspNetPolicy", "grasp planner", "task=insertion", "closed-loop",
      "policy=insertion_state"]),
    pytest.param("run", ["task=grasp", "policy=insertion_state", "budget=smoke"],
                 ["policy=insertion_state", "RslRlPolicy", "closed-loop", "task=grasp", "grasp planner",
                  "policy=antipodal"], marks=pytest.mark.slow),
])
def test_a_policy_of_another_kind_is_refused_before_any_simulation(tmp_path, app, args, words):
    out = tmp_path / "out"
    line = _refusal(_app(app, *args, f"hydra.run.dir={out}"))
    assert all(w in line for w in words), line
    assert "policy=drawer" not in line  # the drawer's closed-loop policies do not fit insertion
    assert not (out / "evaluation.json").exists() and not (out / "journal.jsonl").exists()


class _Stepper(GraspStepPolicy):
    def act(self, obs):
        return None


class _DuckPlanner:  # no GRT base class: taken by its method, as the grasp task calls it
    def plan(self, obs, seed):
        return []


class _DuckClosedLoop:
    def act(self, obs):
        return obs


def test_policy_kinds_follow_what_the_task_calls():
    check_policy_kind(GRASP, _Stepper)
    check_policy_kind(GRASP, _DuckPlanner)
    check_policy_kind(INSERTION, _DuckClosedLoop)
    with pytest.raises(PolicyKindError, match=r"_DuckClosedLoop is a closed-loop .* task=grasp runs a grasp"):
        check_policy_kind(GRASP, _DuckClosedLoop)
    with pytest.raises(PolicyKindError, match=r"policy=mine \(_Stepper\) is a step-by-step .* task=insertion"):
        check_policy_kind(INSERTION, _Stepper, "mine")
    with pytest.raises(PolicyKindError, match="none of the kinds"):
        check_policy_kind(INSERTION, object)


@pytest.mark.parametrize("app", ["select", pytest.param("run", marks=pytest.mark.slow)])
def test_manual_selector_without_handles_is_one_line(tmp_path, app):
    line = _refusal(_app(app, "selector=manual", "budget=smoke", f"hydra.run.dir={tmp_path / 'out'}")
                    if app == "run" else _app(app, "selector=manual", f"out_dir={tmp_path / 'out'}"))
    assert "selector=manual needs handles" in line and "selector.handle_regions=" in line, line


def test_a_folder_given_as_the_object_is_called_a_folder(tmp_path):
    folder = tmp_path / "meshes"
    folder.mkdir()
    trimesh.creation.box((0.05, 0.05, 0.05)).export(folder / "part.obj")
    line = _refusal(_app("evaluate", f"object={folder}", f"hydra.run.dir={tmp_path / 'out'}"))
    assert f"object={folder} is a directory" in line and f"object={folder / 'part.obj'}" in line, line
    assert "not found" not in line


def test_a_path_hydra_cannot_parse_says_how_to_quote_it_and_the_quoted_form_works(tmp_path):
    folder = tmp_path / "my meshes (é)"
    folder.mkdir()
    path = folder / "böx 1.obj"
    trimesh.creation.box((0.05, 0.05, 0.05)).export(path)
    line = _refusal(_app("select", f"object={path}", f"out_dir={tmp_path / 'out'}"))
    assert "must be quoted" in line and f"\"object='{path}'\"" in line, line
    suggested = line.rsplit(": ", 1)[1]  # the command-line argument as the user types it into the shell
    proc = subprocess.run(f"{sys.executable} -m grt.select {suggested} out_dir={tmp_path / 'out'}", shell=True,
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert (tmp_path / "out" / "handles.json").is_file()


def test_cma_es_population_below_two_names_the_setting(tmp_path):
    out = tmp_path / "out"
    line = _refusal(_app("run", "optimizer=cma_es", "budget=smoke", "budget.population=1", f"hydra.run.dir={out}"))
    assert "budget.population=1" in line and "at least 2" in line and "budget.population=2" in line, line
    assert "weights" not in line  # the library's own words
    assert not (out / "journal.jsonl").exists()
