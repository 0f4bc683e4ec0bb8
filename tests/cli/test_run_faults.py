"""Faults and refusals of ``python -m grt.run``, as a user meets them (issue 30): two runs in one folder, a
new run in a finished run's folder, a refused run's folder, a folder that cannot be written, a full disk,
SIGTERM, too many workers. Each is a real ``grt.run`` process: its exit code, one line on stderr, no
traceback, and nothing the user had changed or left behind.

The runs use the toy evaluator of ``tests/runner/_toy_run.py`` (no simulator), except the two that are about
worker processes, which run the real :class:`grt.evaluators.sim.SimEvaluator` pool with the cheap session
of ``tests/evaluators/_toy_session.py``. The full-disk and read-only cases mount a tmpfs or a read-only
bind mount (root only; skipped elsewhere): a chmod does not stop root, which runs these tests here.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from grt.runfolder.lock import LOCK
from tests.runner._toy_run import TOY

ROOT = Path(__file__).resolve().parents[2]
SESSION_PATH = ROOT / "tests" / "evaluators"
RUN = ["budget=smoke", *TOY]
RUN = ["budget=smoke", "object=can", *TOY]  # 7 candidates: the nominal object, then 2 iterations of 3
CANDIDATES = 7
WORKERS = ["budget=smoke", "object=can", "~task.session", "+task.session={_target_:_toy_session.ToySession}",
           "~policy", "+policy={_target_:_toy_session.ToyPolicy}"]  # a real worker pool, no simulator


def _env(workers: bool = False, hold: Path | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("GRT_TEST_INTERRUPT_AT", "GRT_TEST_HOLD_FILE")}
    if hold is not None:  # the toy evaluator waits after the nominal object while this file exists
        env["GRT_TEST_HOLD_FILE"] = str(hold)
    if workers:  # spawned workers import the toy session
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SESSION_PATH), env.get("PYTHONPATH")]))
    return {**env, "WANDB_MODE": "disabled"}


def grt_run(*args: str, workers: bool = False) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.run", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env=_env(workers))


def start(*args: str, workers: bool = False, hold: Path | None = None) -> subprocess.Popen:
    """A run in its own process group (a signal to the group reaches its workers too); with ``hold``, a toy
    run waits after its first journal line while that file exists."""
    if hold is not None:
        hold.touch()
    return subprocess.Popen([sys.executable, "-m", "grt.run", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True, env=_env(workers, hold))


def wait_for_journal(run_dir: Path, proc: subprocess.Popen, timeout: float = 120) -> None:
    end = time.monotonic() + timeout
    while not (run_dir / "journal.jsonl").is_file() or not (run_dir / "journal.jsonl").read_bytes().count(b"\n"):
        if proc.poll() is not None or time.monotonic() > end:
            proc.kill()
            pytest.fail(f"no journal line (rc {proc.returncode}):\n{proc.communicate()[1][-3000:]}")
        time.sleep(0.05)


def error_line(stderr: str, stdout: str = "") -> str:
    """The one ``error:`` line of a refused command (on stderr; nothing of it on stdout; no traceback)."""
    assert "Traceback" not in stderr + stdout and "Logging error" not in stderr + stdout, stderr[-3000:]
    errors = [line for line in stderr.splitlines() if "error" in line.lower()]
    assert len(errors) == 1 and errors[0].startswith("error: "), stderr[-3000:]
    assert "error" not in stdout.lower(), stdout[-3000:]
    return errors[0]


def snapshot(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones too) and its content's hash."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def lines(run_dir: Path) -> int:
    return (run_dir / "journal.jsonl").read_bytes().count(b"\n")


# ------------------------------------------------------------------------------------- one run, one folder

def test_a_second_run_in_a_running_runs_folder_is_refused_naming_its_pid(tmp_path):
    """Issue 30 (2, 3): a resume, or a new run, in the folder of a run in progress is refused (its PID named);
    once it has finished, a new run there is refused without touching a byte of it."""
    run_dir = tmp_path / "run"
    hold = tmp_path / "hold"
    first = start(*RUN, f"hydra.run.dir={run_dir}", hold=hold)
    wait_for_journal(run_dir, first)  # it waits there until the hold file is removed
    seconds = [start(*args) for args in ([f"resume={run_dir}"], [*RUN, "budget.seed=7", f"hydra.run.dir={run_dir}"])]
    for second in seconds:
        out, err = second.communicate(timeout=300)
        assert second.returncode == 2, err[-3000:]
        line = error_line(err, out)
        assert f"{run_dir} is in use by another GRT process (PID {first.pid}" in line, line
    assert first.poll() is None and lines(run_dir) == 1
    hold.unlink()
    out, err = first.communicate(timeout=300)
    assert first.returncode == 0, err[-3000:]
    assert lines(run_dir) == CANDIDATES and not (run_dir / LOCK).exists()

    before = snapshot(run_dir)
    again = grt_run(*RUN, "budget.seed=7", f"hydra.run.dir={run_dir}")
    assert again.returncode == 2
    line = error_line(again.stderr, again.stdout)
    assert f"hydra.run.dir={run_dir} already holds a run" in line and f"resume={run_dir}" in line, line
    assert snapshot(run_dir) == before  # .hydra/config.yaml and overrides.yaml still the first run's


@pytest.mark.slow
def test_two_runs_started_together_in_one_folder_one_is_refused(tmp_path):
    """Issue 30 (2): started at once with different seeds, one runs and the other is refused; the folder's
    summary, run_config.yaml and Hydra record all hold the seed of the one that ran."""
    run_dir = tmp_path / "run"
    procs = {seed: start(*RUN, f"budget.seed={seed}", f"hydra.run.dir={run_dir}") for seed in (0, 7)}
    done = {seed: (p, *p.communicate(timeout=300)) for seed, p in procs.items()}
    codes = sorted(p.returncode for p, _, _ in done.values())
    assert codes == [0, 2], {s: (p.returncode, err[-2000:]) for s, (p, _, err) in done.items()}
    (winner,) = [s for s, (p, _, _) in done.items() if p.returncode == 0]
    loser, (_, out, err) = next((s, v) for s, v in done.items() if s != winner)
    line = error_line(err, out)
    assert f"is in use by another GRT process (PID {procs[winner].pid}" in line or "already holds a run" in line
    assert json.loads((run_dir / "summary.json").read_text())["seed"] == winner
    assert yaml.safe_load((run_dir / "run_config.yaml").read_text())["config"]["budget"]["seed"] == winner
    assert yaml.safe_load((run_dir / ".hydra" / "config.yaml").read_text())["budget"]["seed"] == winner
    assert lines(run_dir) == CANDIDATES and not (run_dir / LOCK).exists()


# ------------------------------------------------------------------------------------ refused: nothing left

def test_a_refused_run_leaves_no_folder_and_says_so_on_stderr(tmp_path):
    """Issue 30 (15, 16): a run refused before any work is one ``error:`` line on stderr (not a log line on
    stdout) and removes the folder it made, saying so; in an empty folder the user had, only its own files go."""
    new = tmp_path / "new" / "a" / "b"
    res = grt_run(*RUN, "budget.trials=0", f"hydra.run.dir={new}")
    assert res.returncode == 2
    line = error_line(res.stderr, res.stdout)
    assert "budget.trials=0 is out of range" in line and f"the new folder {new} was removed" in line, line
    assert not (tmp_path / "new").exists()

    mine = tmp_path / "mine"  # an empty folder the user made (one holding files is refused: issue 40)
    mine.mkdir()
    (tmp_path / "bad.obj").write_text("this is not a mesh\n")
    res = grt_run(*RUN, f"object={tmp_path / 'bad.obj'}", f"hydra.run.dir={mine}")
    assert res.returncode == 2
    line = error_line(res.stderr, res.stdout)
    assert "bad.obj" in line and f"nothing was saved in {mine}" in line, line
    assert mine.is_dir() and list(mine.iterdir()) == []


def test_a_folder_that_cannot_be_written_is_one_line(tmp_path):
    """Issue 30 (7): a read-only folder (a read-only bind mount, which stops root too, unlike a chmod), as the
    run folder and as its parent; where no mount can be made (not root), a file where the folder should go."""
    source, readonly = tmp_path / "source", tmp_path / "ro"
    source.mkdir()
    readonly.mkdir()
    if subprocess.run(["mount", "--bind", "-o", "ro", str(source), str(readonly)], capture_output=True).returncode:
        (tmp_path / "file").write_text("x")
        res = grt_run(*RUN, f"hydra.run.dir={tmp_path / 'file' / 'run'}")
        assert res.returncode == 2
        assert "cannot write the run folder" in error_line(res.stderr, res.stdout)
        return
    try:
        for run_dir in (readonly, readonly / "run"):
            res = grt_run(*RUN, f"hydra.run.dir={run_dir}")
            assert res.returncode == 2, res.stderr[-3000:]
            line = error_line(res.stderr, res.stdout)
            assert f"cannot write the run folder {run_dir}: Read-only file system" in line, line
    finally:
        subprocess.run(["umount", str(readonly)], check=True)
    assert list(source.iterdir()) == []


# ------------------------------------------------------------------------------------------ stopped mid-run

@pytest.mark.slow
def test_a_full_disk_is_one_line_with_the_resume_command(tmp_path):
    """Issue 30 (6): the disk fills up while the run goes on: one line naming the disk and the resume command,
    exit code 1, no traceback or logging error; once there is space, ``resume=DIR`` finishes the run."""
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", str(disk)],
                      capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        run_dir = disk / "run"
        hold = tmp_path / "hold"
        proc = start(*RUN, f"hydra.run.dir={run_dir}", hold=hold)
        wait_for_journal(run_dir, proc)
        with open(disk / "filler", "wb") as filler, pytest.raises(OSError, match="No space left"):
            while True:
                filler.write(b"\0" * 65536)
                filler.flush()
        hold.unlink()  # the run goes on, on a full disk
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 1, err[-3000:]
        line = error_line(err, out)
        assert f"the disk of {disk} is full" in line and f"python -m grt.run resume={run_dir}" in line, line
        (disk / "filler").unlink()
        res = grt_run(f"resume={run_dir}")
        assert res.returncode == 0, res.stderr[-3000:]
        assert lines(run_dir) == CANDIDATES and (run_dir / "summary.json").is_file()
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=True)


def test_sigterm_stops_a_run_like_ctrl_c_and_resume_finishes_it(tmp_path):
    """Issue 30 (9): SIGTERM (``kill``, ``timeout``, schedulers) is one line with the resume command, exit code
    143; ``resume=DIR`` then finishes the run."""
    run_dir = tmp_path / "run"
    proc = start(*RUN, f"hydra.run.dir={run_dir}", hold=tmp_path / "hold")
    wait_for_journal(run_dir, proc)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err[-3000:]
    assert "Traceback" not in err + out
    assert err.strip().splitlines()[-1] == f"terminated (SIGTERM); continue this run with: python -m grt.run " \
                                           f"resume={run_dir}"
    assert lines(run_dir) == 1 and not (run_dir / LOCK).exists()
    res = grt_run(f"resume={run_dir}")
    assert res.returncode == 0, res.stderr[-3000:]
    assert lines(run_dir) == CANDIDATES


@pytest.mark.slow
def test_sigterm_to_a_run_with_workers_leaves_them_quiet(tmp_path):
    """Issue 30 (9): SIGTERM to the whole process group (what ``timeout`` and schedulers send) of a run with
    a worker pool: the run's one line, no worker traceback (EOFError); the resume finishes it."""
    run_dir = tmp_path / "run"
    proc = start(*WORKERS, "budget.population=4", "budget.iterations=5", "budget.workers=2",
                 f"hydra.run.dir={run_dir}", workers=True)
    wait_for_journal(run_dir, proc)
    os.killpg(proc.pid, signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    time.sleep(1.0)  # the workers' last words, if any, reach the pipe's other readers first
    assert proc.returncode == 143, err[-3000:]
    assert "Traceback" not in err + out and "EOFError" not in err + out, err[-3000:]
    assert err.strip().splitlines()[-1].startswith("terminated (SIGTERM); continue this run with:")
    res = grt_run(f"resume={run_dir}", workers=True)
    assert res.returncode == 0, res.stderr[-3000:]
    assert lines(run_dir) == 1 + 4 * 5


@pytest.mark.slow
def test_too_many_workers_are_clamped_with_the_numbers(tmp_path):
    """Issue 30 (5): ``budget.workers=64`` starts as many workers as the cores and memory hold, warns with
    the numbers and records them in summary.json."""
    run_dir = tmp_path / "run"
    res = grt_run(*WORKERS, "budget.workers=64", f"hydra.run.dir={run_dir}", workers=True)
    assert res.returncode == 0, res.stderr[-3000:]
    used = json.loads((run_dir / "summary.json").read_text())["workers"]
    assert used["requested"] == 64 and 1 <= used["used"] <= min(used["cores"], len(os.sched_getaffinity(0)))
    assert f"workers=64: starting {used['used']} simulator workers" in res.stdout + res.stderr
    assert f"{used['cores']} CPU cores" in res.stdout + res.stderr
