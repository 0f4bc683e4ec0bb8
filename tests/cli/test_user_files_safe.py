"""Nothing the user has is overwritten (issue 40): ``grt.deform --out`` over an input or another file, a new
run in a folder holding the user's files, a resume of a finished run, an edited run record, an empty
``resume=``; and the resume command printed for a folder with spaces and non-ASCII letters works when pasted.

The runs are real ``grt.run`` processes with the toy evaluator of ``tests/runner/_toy_run.py`` (no simulator),
one finished run made once for the module and copied for each test.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh
from omegaconf import OmegaConf

import grt.cli.deform as deform_cli
from grt.objects import get_object
from tests.cli.test_run_faults import RUN, error_line, grt_run, snapshot

ROOT = Path(__file__).resolve().parents[2]


def _in_process(main, argv, capsys) -> tuple[int, str]:
    with pytest.raises(SystemExit) as info:
        main(argv)
    return info.value.code, capsys.readouterr().err


# ------------------------------------------------------------------------------------------- grt.deform

def test_deform_never_writes_over_its_input_and_asks_before_replacing_a_file(tmp_path, capsys):
    """``--out`` naming the input mesh (or a link to it) is refused, ``--overwrite`` or not; an ``--out`` that
    is another existing file needs ``--overwrite``."""
    mesh = tmp_path / "can.obj"
    get_object("can").export(mesh)
    (tmp_path / "h.txt").write_text("0 0 0 0.1\n")
    (tmp_path / "a.txt").write_text("5 0 0 0\n6 0 0 0\n7 0 0 0\n")
    (tmp_path / "link.obj").symlink_to(mesh)
    (tmp_path / "mine.obj").write_text("the user's own file\n")
    before = snapshot(tmp_path)
    targets = ["--handles", str(tmp_path / "h.txt"), "--anchors", str(tmp_path / "a.txt")]
    for out, extra, message in ((mesh, [], "is the input mesh"), (tmp_path / "link.obj", ["--overwrite"],
                                                                    "is the input mesh"),
                                (tmp_path / "mine.obj", [], "already exists; give another --out, or --overwrite")):
        code, err = _in_process(deform_cli.main, [str(mesh), *targets, "--out", str(out), *extra], capsys)
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert snapshot(tmp_path) == before  # not a byte changed
    assert deform_cli.main([str(mesh), *targets, "--out", str(tmp_path / "mine.obj"), "--overwrite"]) == 0
    assert len(trimesh.load(tmp_path / "mine.obj", process=False).vertices) == len(get_object("can").vertices)


# ------------------------------------------------------------------------------------------------ resume=

@pytest.mark.parametrize("app", ["run", "train", "blueteam"])
def test_an_empty_resume_is_refused_not_a_new_run(app, tmp_path, capsys, monkeypatch):
    """``resume=$RUN`` with ``RUN`` unset reaches the app as ``resume=``: refused before Hydra starts (nothing
    written), not taken for a new run."""
    import importlib

    monkeypatch.chdir(tmp_path)
    cli = importlib.import_module(f"grt.cli.{app}").cli
    code, err = _in_process(cli, ["resume=", f"hydra.run.dir={tmp_path / 'new'}"], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("error: 'resume=': resume= is empty (an unset shell variable?)") and "resume=DIR" in err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------- a new run, a new folder

def test_a_new_run_in_a_folder_of_the_users_files_is_refused_and_changes_nothing(tmp_path):
    """The user's own ``summary.json``, ``nominal.obj``, ``.hydra/config.yaml`` and notes: ``grt.run
    hydra.run.dir=DIR`` overwrote three of them; now it is one line, exit 2, every byte as it was."""
    mine = tmp_path / "mine"
    (mine / ".hydra").mkdir(parents=True)
    for name, text in (("summary.json", '{"mine": 1}'), ("nominal.obj", "v 0 0 0\n"),
                       (".hydra/config.yaml", "object: mine\n"), ("notes.txt", "my notes\n")):
        (mine / name).write_text(text)
    before = snapshot(mine)
    res = grt_run(*RUN, f"hydra.run.dir={mine}")
    assert res.returncode == 2, res.stderr[-3000:]
    line = error_line(res.stderr, res.stdout)
    assert line.startswith(f"error: {mine} is not empty (it holds .hydra, nominal.obj, notes.txt, summary.json)"), line
    assert "hydra.run.dir=PATH" in line, line
    assert snapshot(mine) == before


def test_a_finished_evaluations_folder_keeps_its_record(tmp_path):
    """``grt.evaluate hydra.run.dir=DIR`` of a finished evaluation replaced its ``.hydra`` record; refused now."""
    folder = tmp_path / "evaluation"
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "config.yaml").write_text("object: can\n")
    (folder / "evaluate.log").write_text("")
    (folder / "evaluation.json").write_text('{"score": 0.5}')
    before = snapshot(folder)
    res = subprocess.run([sys.executable, "-m", "grt.evaluate", "object=can", f"hydra.run.dir={folder}"], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr[-3000:]
    line = error_line(res.stderr, res.stdout)
    assert f"{folder} is not empty (it holds .hydra, evaluate.log, evaluation.json)" in line, line
    assert "a new python -m grt.evaluate starts only in a new or empty folder" in line
    assert snapshot(folder) == before


def test_which_folders_a_new_run_may_take(tmp_path):
    """New or empty (a lock file left by a SIGKILL is nothing), Hydra's files of a start killed before it saved
    anything, or a study / training its app continues in place; anything else is refused."""
    from grt.runfolder.lock import LOCK, FolderNotEmptyError, check_new_folder

    def held(folder: Path) -> set[str]:
        return {p.name for p in folder.iterdir()}

    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / LOCK).write_text("123\n")
    killed = tmp_path / "killed"
    (killed / ".hydra").mkdir(parents=True)
    for name in ("config.yaml", "hydra.yaml", "overrides.yaml"):
        (killed / ".hydra" / name).write_text("{}\n")
    (killed / "run.log").write_text("")
    study = tmp_path / "study"
    (study / ".hydra").mkdir(parents=True)
    (study / ".hydra" / "config.yaml").write_text("run: /r\nblueteam: {}\n")
    (study / "last.pt").write_bytes(b"weights")
    for folder, app in ((empty, "run"), (killed, "run"), (study, "blueteam")):
        check_new_folder(folder, held(folder), app, f"{app}.log")
    for folder, app in ((killed, "evaluate"), (study, "run"), (study, "train")):
        with pytest.raises(FolderNotEmptyError, match="is not empty"):
            check_new_folder(folder, held(folder), app, f"{app}.log")
    (killed / ".hydra" / "notes.txt").write_text("mine\n")  # not Hydra's: the user's
    with pytest.raises(FolderNotEmptyError):
        check_new_folder(killed, held(killed), "run", "run.log")


# ------------------------------------------------------------------------------- resuming a finished run

@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """One finished toy run (7 candidates, CrashShapes among them)."""
    run_dir = tmp_path_factory.mktemp("finished") / "run"
    res = grt_run(*RUN, f"hydra.run.dir={run_dir}")
    assert res.returncode == 0, res.stderr[-3000:]
    return run_dir


@pytest.fixture
def run_copy(finished, tmp_path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(finished, copy)
    return copy


def test_a_finished_run_resumed_has_nothing_to_do_and_changes_nothing(run_copy):
    """``resume=DIR`` of a finished run rewrote summary.json (its wall time, its trials per node); now it says
    there is nothing to do and not a byte of the folder changes (Hydra's files of a resume included). More
    fresh episodes (``budget.confirm_trials=N``) are work: done, then nothing to do again."""
    before = snapshot(run_copy)
    res = grt_run(f"resume={run_copy}", "budget.workers=3")
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert res.stdout.strip().startswith(f"nothing to do: {run_copy} is a finished run (7 candidates"), res.stdout
    assert snapshot(run_copy) == before
    res = grt_run(f"resume={run_copy}", "budget.confirm_trials=4")
    assert res.returncode == 0, res.stderr[-3000:]
    assert json.loads((run_copy / "summary.json").read_text())["confirm"]["trials"] == 4
    from grt.config import make_plan
    from grt.runfolder.record import load_run_config
    from grt.runner import nothing_to_do

    cfg = OmegaConf.create(load_run_config(run_copy))  # as the command resolves it, in this process
    cfg.budget.confirm_trials = 4
    assert nothing_to_do(run_copy, make_plan(cfg)).startswith("nothing to do:")  # confirmed: nothing to do again
    cfg.budget.confirm_trials = 6
    assert nothing_to_do(run_copy, make_plan(cfg)) is None


def test_an_edited_record_is_refused_before_anything_is_written(run_copy):
    """``run_config.yaml`` edited (object can -> bottle): ``resume=`` overwrote nominal.obj, then failed with a
    traceback. Now one line naming what differs, before Hydra or the run writes anything."""
    record = run_copy / "run_config.yaml"
    record.chmod(0o644)
    record.write_text(record.read_text().replace("\n  object: can\n", "\n  object: bottle\n"))
    before = snapshot(run_copy)
    res = grt_run(f"resume={run_copy}")
    assert res.returncode == 2, res.stderr[-3000:]
    line = error_line(res.stderr, res.stdout)
    assert "the run's record was edited after it started" in line, line
    assert "object (run_config.yaml: bottle, .hydra/config.yaml: can)" in line and "restore run_config.yaml" in line
    assert snapshot(run_copy) == before


def test_an_edited_record_without_hydras_is_refused_by_its_object(run_copy):
    """No second record to compare with (a run started from Python, ``grt.runner.run``): the object the edited
    record gives is checked against the run's nominal.obj and journal, before anything is written."""
    from grt.errors import UserError
    from grt.runfolder.record import load_run_config
    from grt.runner import run

    shutil.rmtree(run_copy / ".hydra")
    (run_copy / "summary.json").unlink()
    journal = run_copy / "journal.jsonl"
    journal.write_bytes(b"".join(journal.read_bytes().splitlines(keepends=True)[:3]))  # stopped mid-way
    record = run_copy / "run_config.yaml"
    record.chmod(0o644)
    record.write_text(record.read_text().replace("\n  object: can\n", "\n  object: bottle\n"))
    cfg = OmegaConf.create(load_run_config(run_copy))
    cfg.resume = str(run_copy)
    before = snapshot(run_copy)
    with pytest.raises(UserError, match=r"the object its record gives \(object=bottle, .* is not the object the run "
                                        r"was made with"):
        run(cfg)
    assert snapshot(run_copy) == before


def test_report_on_a_stopped_run_gives_a_resume_command_that_works_when_pasted(finished, tmp_path, capsys):
    """``grt.report`` on a run stopped mid-way says how to finish it, as ``--html`` does; in a folder named with
    spaces, brackets and non-ASCII letters the printed command, run through a shell as printed, finishes it."""
    import grt.cli.report as report_cli
    from tests.cli.test_run_faults import _env

    run_dir = tmp_path / "mes runs (été)" / "run 1"
    shutil.copytree(finished, run_dir)
    (run_dir / "summary.json").unlink()
    journal = run_dir / "journal.jsonl"
    journal.write_bytes(b"".join(journal.read_bytes().splitlines(keepends=True)[:3]))  # stopped mid-way
    code, err = _in_process(report_cli.main, [str(run_dir)], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"error: {run_dir} is a run that has not finished (no summary.json; 3 candidate(s) in its "
                          "journal): finish it with python -m grt.run "), err
    command = err.split("finish it with ", 1)[1].split(", then report on it")[0]
    assert command == f"python -m grt.run 'resume=\"{run_dir}\"'", command
    res = subprocess.run(["bash", "-c", command.replace("python", sys.executable, 1)], cwd=ROOT, capture_output=True,
                         text=True, timeout=300, env=_env())
    assert res.returncode == 0, res.stderr[-3000:]
    assert journal.read_bytes().count(b"\n") == 7 and (run_dir / "summary.json").is_file()


def test_a_refused_run_removes_only_the_folders_it_made_never_the_users_empty_ones_above(tmp_path):
    """A refused ``grt.run`` removes the run folder it made (``outputs/<task>/...`` under the working folder) and
    nothing above: an empty working folder, and an empty folder above it, stay. Before, the folders made
    were noted relative and removed absolute, so every empty folder up the path went too."""
    work = tmp_path / "empty_parent" / "work"
    work.mkdir(parents=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "WANDB_MODE": "disabled"}
    res = subprocess.run([sys.executable, "-m", "grt.run", "object=/no/such/mesh.obj"], cwd=work,
                         capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 2 and "mesh file not found" in error_line(res.stderr, res.stdout)
    assert "the new folder" in res.stderr and "was removed" in res.stderr
    assert work.is_dir() and list(work.iterdir()) == []  # outputs/... made by the run: gone; the rest stays
