"""``resume=DIR`` alone continues a run with its own config; a resume that would change the run, or of a
folder that is not a run, is refused before any file is touched; Ctrl-C names the command that continues.

The runs are real ``python -m grt.run`` processes with the toy evaluator of ``_toy_run`` (no simulator).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from grt.runfolder.record import RUN_CONFIG, ResumeError, resume_or
from grt.runfolder.resume import resume_overrides
from tests.runner._toy_run import TOY

ROOT = Path(__file__).resolve().parents[2]
# Not the defaults (budget=quick, selector.k=8, optimizer=topdm, object=mug): a resume must keep each of them.
# (The can also makes each toy run half as long: no remeshing, a small mesh to check.)
FIRST = ["budget=smoke", "selector.k=3", "optimizer=gaussian", "object=can", *TOY]


def grt_run(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.run", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "WANDB_MODE": "disabled", **(env or {})})


def tree(folder: Path) -> dict[str, str]:
    """Every path under ``folder`` with its mode and, for a file, the digest of its bytes."""
    return {str(p.relative_to(folder)): f"{p.stat().st_mode:o} "
            + (hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir")
            for p in sorted(folder.rglob("*"))}


def journal_lines(run_dir: Path) -> int:
    return len((run_dir / "journal.jsonl").read_text().splitlines())


@pytest.fixture(scope="module")
def interrupted(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """A run stopped by Ctrl-C in its third evaluation: S0 and one candidate are in its journal."""
    run_dir = tmp_path_factory.mktemp("resume") / "run"
    res = grt_run(*FIRST, f"hydra.run.dir={run_dir}", env={"GRT_TEST_INTERRUPT_AT": "3"})
    return run_dir, res


@pytest.fixture
def run_dir(interrupted, tmp_path) -> Path:
    """A copy of the interrupted run, for one test to continue or change."""
    copy = tmp_path / "run"
    shutil.copytree(interrupted[0], copy)
    return copy


def test_ctrl_c_is_one_line_naming_the_command_that_continues(interrupted):
    run_dir, res = interrupted
    out = res.stdout + res.stderr
    assert res.returncode == 130, out
    assert "Traceback" not in out
    lines = [line for line in out.splitlines() if "interrupted" in line]
    assert len(lines) == 1 and lines[0].endswith(f"continue this run with: python -m grt.run resume={run_dir}")
    assert journal_lines(run_dir) == 2
    assert (run_dir / RUN_CONFIG).stat().st_mode & 0o222 == 0, "the run's record must be read-only"


def test_resume_alone_continues_with_the_runs_own_config(run_dir):
    record, hydra_record = (run_dir / RUN_CONFIG).read_bytes(), (run_dir / ".hydra" / "config.yaml").read_bytes()
    res = grt_run(f"resume={run_dir}", "budget.workers=1")  # a setting that does not change the search
    assert res.returncode == 0, res.stdout + res.stderr
    assert journal_lines(run_dir) == 1 + 3 * 2  # budget=smoke's, not the default budget=quick's 1 + 8 * 8
    summary = json.loads((run_dir / "summary.json").read_text())
    assert (summary["optimizer"], summary["num_handles"]) == ("gaussian", 3)
    assert (summary["population"], summary["iterations"], summary["trials"]) == (3, 2, 2)
    new = [json.loads(line) for line in (run_dir / "journal.jsonl").read_text().splitlines()[2:]]
    assert summary["evaluated_this_session"] == sum(r["valid"] for r in new)  # implausible ones are not simulated
    # the records of the run's start are untouched; Hydra's files of the resume go to .hydra/resume
    assert (run_dir / RUN_CONFIG).read_bytes() == record
    assert (run_dir / ".hydra" / "config.yaml").read_bytes() == hydra_record
    assert "optimizer=gaussian" in (run_dir / ".hydra" / "resume" / "overrides.yaml").read_text()


def test_a_resume_that_would_change_the_run_is_refused_before_any_file(run_dir):
    before = tree(run_dir)
    res = grt_run(f"resume={run_dir}", "selector=all", "object=bottle", "budget.trials=2")
    assert res.returncode == 2, res.stdout + res.stderr
    assert "Traceback" not in res.stderr and res.stderr.count("\n") == 1
    assert "selector (the run's: heuristic, given: all), object (the run's: can, given: bottle)" in res.stderr
    assert "budget.trials" not in res.stderr  # the run's own value: no change
    assert "start a new run" in res.stderr
    assert tree(run_dir) == before


@pytest.mark.parametrize(("folder", "message"), [(None, "no such folder"), ("notes.txt", "not a GRT run folder")])
def test_resume_of_a_folder_that_is_not_a_run_creates_nothing(folder, message, tmp_path):
    target = tmp_path / "target"
    if folder is not None:
        target.mkdir()
        (target / folder).write_text("mine\n")
    before = tree(tmp_path)
    res = grt_run(f"resume={target}")
    assert res.returncode == 2, res.stdout + res.stderr
    assert message in res.stderr and "nothing to resume" in res.stderr and "Traceback" not in res.stderr
    assert tree(tmp_path) == before  # no folder, no .hydra/, no run.log


@pytest.mark.parametrize("given", [
    [], ["budget=smoke", "optimizer=gaussian", "selector.k=3", "budget.trials=2"],  # the run's own values
    ["budget.workers=4"], ["evaluator.workers=1"], ["logger=wandb", "logger.mode=offline"],
    ["paths.cache_dir=/tmp/cache"], ["hydra.verbose=true"], ["hydra/job_logging=disabled"],
])
def test_a_resume_is_the_runs_own_command_plus_what_cannot_change_it(given, interrupted):
    run_dir = interrupted[0]
    resume = f"resume={run_dir}"
    new = resume_overrides([*given, resume])
    free = [g for g in given if not g.startswith(("budget=", "optimizer=", "selector.", "budget.trials"))]
    assert new == [*FIRST, "hydra.output_subdir=.hydra/resume", *free, resume]


def test_a_free_override_replaces_the_runs_own_one(run_dir):
    record = run_dir / RUN_CONFIG
    record.chmod(0o644)
    record.write_text(record.read_text().replace("overrides:\n", "overrides:\n- logger.mode=offline\n", 1))
    new = resume_overrides(["logger=none", f"resume={run_dir}"])
    assert "logger.mode=offline" not in new and "logger=none" in new


@pytest.mark.parametrize(("given", "key"), [
    ("budget=paper", "budget"), ("budget.seed=1", "budget.seed"), ("budget.sigma=0.5", "budget.sigma"),
    ("optimizer=cma_es", "optimizer"), ("selector.k=8", "selector.k"), ("task=insertion", "task"),
    ("policy=insertion_state", "policy"), ("+task.ci=wilson", "task.ci"), ("deformer.method=apap", "deformer.method"),
    ("~budget.tau", "budget.tau"), ("experiment=table1_grasp", "experiment"), ("paths.output_dir=/tmp/x", "paths.output_dir"),
])
def test_a_resume_that_changes_the_search_names_the_key(given, key, interrupted):
    with pytest.raises(ResumeError, match=rf"^resume=\S+: {key} \(the run's: .*start a new run"):
        resume_overrides([f"resume={interrupted[0]}", given])


def test_a_run_from_before_run_config_yaml_resumes_from_hydras_record(run_dir):
    (run_dir / RUN_CONFIG).unlink()
    assert resume_overrides([f"resume={run_dir}"]) == [*FIRST, "hydra.output_subdir=.hydra/resume",
                                                       f"resume={run_dir}"]
    with pytest.raises(ResumeError, match="selector"):
        resume_overrides([f"resume={run_dir}", "selector=all"])
    (run_dir / "journal.jsonl").unlink()  # Hydra's files alone do not make a run
    with pytest.raises(ResumeError, match="not a GRT run folder"):
        resume_overrides([f"resume={run_dir}"])


def test_hydra_never_gets_a_run_folder_that_is_not_a_run(run_dir, tmp_path):
    """The hydra.run.dir resolver refuses too, for an app started some other way than ``python -m grt.run``."""
    assert resume_or(None, "outputs/new") == "outputs/new"
    assert resume_or(str(run_dir), "outputs/new") == str(run_dir)
    with pytest.raises(ValueError, match="no such folder"):
        resume_or(str(tmp_path / "missing"), "outputs/new")
