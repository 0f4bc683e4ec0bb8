"""Faults around the worker pool (issue 40): a journal that becomes unwritable while the pool's trials come in,
and the per-task default of ``trial_timeout``. Real worker processes with the cheap session of
``_toy_session.py``."""

from __future__ import annotations

import errno
import subprocess

import numpy as np
import pytest

from grt.evaluators.sim import SimEvaluator
from grt.geometry.deform import ShapeDeformer
from grt.journal import Journal
from grt.optimizers import TOPDMOptimizer
from grt.redteam import RedTeamLoop
from grt.runfolder.record import storage_error


def _mount(*args: str) -> bool:
    return subprocess.run(["mount", *args], capture_output=True).returncode == 0


def test_a_journal_that_becomes_unwritable_mid_run_is_one_line_with_the_resume_command(toy_configs, u_mesh, tmp_path):
    """The pool took the journal's OSError (raised in its on_trial call-back) for a dead worker's: the run ended
    in "the evaluator returned 2 of 3 candidates' results" with no resume line. Now the OSError is the run's
    (a read-only bind mount made mid-run, which stops root too), and it is the full disk's one line."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "run_config.yaml").write_text("grt_format: 2\n")  # a run folder: its line names the resume
    if not _mount("--bind", str(run_dir), str(run_dir)):
        pytest.skip("cannot bind-mount here (needs root)")
    journal = run_dir / "journal.jsonl"
    try:
        v = u_mesh.vertices
        top = np.flatnonzero(v[:, 2] > 0.05 - 1e-6)
        deformer = ShapeDeformer(u_mesh, top[np.argsort(v[top, 0])[[0, -1]]], np.flatnonzero(v[:, 2] < 1e-6))
        task, policy = toy_configs()
        with SimEvaluator(task, policy, workers=1, nominal=u_mesh, progress=False,
                          cache_dir=str(tmp_path / "coacd")) as ev:
            loop = RedTeamLoop(deformer, TOPDMOptimizer(2, population=3, sigma=0.02, seed=0), ev, Journal(journal),
                               [11, 12], iterations=1,
                               on_candidate=lambda rec: _mount("-o", "remount,ro,bind", str(run_dir)))
            with pytest.raises(OSError) as err:
                loop.run()
    finally:
        subprocess.run(["umount", str(run_dir)], check=True)
    assert err.value.errno == errno.EROFS and err.value.filename == str(journal), err.value
    assert journal.read_bytes().count(b"\n") == 1  # the nominal object, journaled before the folder went read-only
    assert storage_error(err.value, run_dir) == (
        f"cannot write the run's files (Read-only file system, writing {journal}); the journal keeps every finished "
        f"candidate: make the folder writable, then continue with: python -m grt.run resume={run_dir}")


def test_the_default_trial_timeout_is_the_tasks_own_from_its_episode_length(toy_configs):
    """``evaluator.trial_timeout=auto`` (the default; 600 s for every task before): 3x the longest a trial of the
    task takes at its measured worst-case step times, so a stopped worker of a drawer run is caught in about
    half a minute; a served policy and a task that gives no bound keep 600 s, and a number given is used."""
    from grt.config import plain
    from grt.evaluators.sim import default_trial_timeout
    from grt.tasks import session_class
    from grt.tasks.base import FALLBACK_TRIAL_TIMEOUT, TRIAL_TIMEOUT_MARGIN
    from tests.runner.conftest import compose_run

    found = {}
    for task, policy in (("grasp", "antipodal"), ("insertion", "insertion_state"), ("drawer", "drawer_state"),
                         ("drawer", "remote"), ("drawer", "drawer_state task.session.max_steps=100")):
        cfg = compose_run([f"task={task}", *f"policy={policy}".split()])
        task_cfg = plain(cfg.task)
        found[task, policy] = default_trial_timeout(task_cfg, plain(cfg.policy))
        seconds = session_class(task_cfg).trial_seconds(**{k: v for k, v in task_cfg["session"].items()
                                                           if k != "_target_"})
        if policy != "remote":
            assert found[task, policy] == round(TRIAL_TIMEOUT_MARGIN * seconds, 1)
    assert 10 < found["drawer", "drawer_state"] < 60 < found["insertion", "insertion_state"] < FALLBACK_TRIAL_TIMEOUT
    assert 60 < found["grasp", "antipodal"] < FALLBACK_TRIAL_TIMEOUT
    assert found["drawer", "drawer_state task.session.max_steps=100"] < found["drawer", "drawer_state"]
    assert found["drawer", "remote"] == FALLBACK_TRIAL_TIMEOUT  # a served policy's replies are the server's

    task, policy = toy_configs()  # a session that gives no bound of its own
    assert SimEvaluator(task, policy, workers=1, collision="coacd", progress=False).pool.trial_timeout == \
        FALLBACK_TRIAL_TIMEOUT
    assert SimEvaluator(task, policy, workers=1, collision="coacd", progress=False,
                        trial_timeout=12.5).pool.trial_timeout == 12.5
