"""The worker pool with a real (cheap) task session: determinism, crashes, exceptions."""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from grt.evaluators.pool import WORKER_MB, WorkerPool, worker_limits
from grt.evaluators.sim import SimEvaluator
from grt.targets import ClassError

HERE = Path(__file__).parent
ROOT = HERE.parents[1]

SEEDS = [11, 12, 13, 14, 15, 16]


def _evaluate(task, policy, meshes, workers, cache_dir, **kwargs):
    with SimEvaluator(task, policy, workers=workers, collision="fast", nominal=meshes[0], progress=False,
                      cache_dir=str(cache_dir), **kwargs) as ev:
        return ev.evaluate(meshes, SEEDS)


def _modes(results):
    return [[(t.seed, t.mode, t.score) for t in r.trials] for r in results]


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("coacd")


@pytest.fixture(scope="module")
def reference(toy_configs, u_mesh, u_deformed, cache_dir):
    """Outcomes of a healthy session with one worker on [nominal, deformed]."""
    task, policy = toy_configs()
    return _evaluate(task, policy, [u_mesh, u_deformed], 1, cache_dir)


def test_same_results_with_one_or_two_workers(toy_configs, u_mesh, u_deformed, reference, cache_dir):
    task, policy = toy_configs()
    two = _evaluate(task, policy, [u_mesh, u_deformed], 2, cache_dir, chunk_size=2)
    assert _modes(two) == _modes(reference)
    assert [r.score for r in two] == [r.score for r in reference]
    assert [t.seed for t in two[0].trials] == SEEDS
    assert len({t.mode for r in reference for t in r.trials}) == 2  # the toy task does discriminate
    assert all(r.wall_s > 0 and r.info["parts"] >= 2 for r in reference)


def test_exception_in_a_trial_is_a_sim_error(toy_configs, u_mesh, cache_dir):
    task, policy = toy_configs(raise_on=13)
    (result,) = _evaluate(task, policy, [u_mesh], 2, cache_dir)
    bad = result.trials[SEEDS.index(13)]
    assert bad.mode == "sim_error" and "physics exploded on seed 13" in bad.info["error"]
    assert result.outcomes.get("sim_error") == 1
    assert len(result.valid_trials) == len(SEEDS) - 1


def test_a_worker_that_always_dies_is_restarted_then_gives_up(toy_configs, u_mesh, reference, cache_dir):
    task, policy = toy_configs(crash_on=12)
    (result,) = _evaluate(task, policy, [u_mesh], 2, cache_dir, max_retries=1)
    bad = result.trials[SEEDS.index(12)]
    assert bad.mode == "sim_error" and "exit code 3" in bad.info["error"] and "2 times" in bad.info["error"]
    # Every other seed still ran, with the outcome a healthy worker gives.
    for got, want in zip(result.trials, reference[0].trials, strict=True):
        if got.seed != 12:
            assert (got.mode, got.score) == (want.mode, want.score)


def test_a_transient_crash_is_rerun(toy_configs, u_mesh, reference, cache_dir, tmp_path):
    task, policy = toy_configs(crash_on=14, crash_once_marker=str(tmp_path / "crashed"))
    with SimEvaluator(task, policy, workers=1, nominal=u_mesh, progress=False, cache_dir=str(cache_dir)) as ev:
        (result,) = ev.evaluate([u_mesh], SEEDS)
        assert ev.pool.restarts == 1
    assert (tmp_path / "crashed").exists()
    assert _modes([result]) == _modes(reference[:1])


def test_a_schedulers_time_limit_warning_does_not_kill_the_workers(toy_configs, u_mesh, reference, cache_dir):
    # SLURM signals every process of a job before its time limit (submitit's --signal=USR2@120): the run's
    # own process decides what to do (requeue, or stop with the command that continues it); its workers stay
    task, policy = toy_configs()
    with SimEvaluator(task, policy, workers=1, nominal=u_mesh, progress=False, cache_dir=str(cache_dir)) as ev:
        (first,) = ev.evaluate([u_mesh], SEEDS)
        (pid,) = {t.info["pid"] for t in first.trials}
        os.kill(pid, signal.SIGUSR2)
        (again,) = ev.evaluate([u_mesh], SEEDS)
        assert ev.pool.restarts == 0 and {t.info["pid"] for t in again.trials} == {pid}
    assert _modes([again]) == _modes(reference[:1])


def test_a_session_that_cannot_be_built_is_a_clear_error(toy_configs, u_mesh, cache_dir):
    """One line (a user error, exit code 2 in the apps): the class, the worker's error and where its traceback is."""
    task, policy = toy_configs(fail_build=True)
    with pytest.raises(ClassError, match=r"task.session \(_toy_session.ToySession\) could not be built in an "
                       "evaluator worker: RuntimeError: toy session refuses to build") as info:
        _evaluate(task, policy, [u_mesh], 1, cache_dir)
    (line,) = str(info.value).splitlines()
    trace = Path(line.rsplit("the whole traceback: ", 1)[1].rstrip(")"))
    assert "Traceback (most recent call last)" in trace.read_text() and "def __init__" not in line


def test_render_writes_one_picture_per_trial(toy_configs, u_mesh, cache_dir, tmp_path):
    task, policy = toy_configs()
    _evaluate(task, policy, [u_mesh], 1, cache_dir, render_dir=str(tmp_path / "renders"))
    pictures = sorted(p.name for p in (tmp_path / "renders").iterdir())
    assert pictures == sorted(f"candidate000_seed{s}.png" for s in SEEDS)


def test_configs_must_be_plain_dicts(u_mesh):
    with pytest.raises(ValueError, match="plain dict"):
        SimEvaluator(OmegaConf.create({"session": {}}), {}, nominal=u_mesh)


def test_the_workers_swap_in_another_policy_for_one_call_and_give_their_own_back(toy_configs, u_mesh, reference,
                                                                                  cache_dir):
    task, policy = toy_configs()
    strict = {**policy, "fill": 0.99}  # no seed fills its bar: every trial fails under this policy
    with SimEvaluator(task, policy, workers=2, collision="fast", nominal=u_mesh, progress=False,
                      cache_dir=str(cache_dir)) as ev:
        (swapped,) = ev.evaluate([u_mesh], SEEDS, policy=strict)
        (again,) = ev.evaluate([u_mesh], SEEDS, policy=strict)
        (own,) = ev.evaluate([u_mesh], SEEDS)  # no policy given: the pool's own, on the same workers
        (broken,) = ev.evaluate([u_mesh], SEEDS, policy={**policy, "_target_": "no.such.Policy"})
    assert reference[0].score > 0 and swapped.score == again.score == 0.0
    assert _modes([own]) == _modes(reference[:1])
    assert all(t.mode == "sim_error" and "policy failed" in t.info["error"] for t in broken.trials)


def test_workers_are_bounded_by_the_cores_and_the_memory(toy_configs, caplog):
    """Issue 30 (5): more workers than this machine holds are not started; the pool says so with the numbers."""
    cores = len(os.sched_getaffinity(0))
    limits = worker_limits(10_000)
    assert limits["requested"] == 10_000 and limits["cores"] == cores
    assert 1 <= limits["used"] <= cores and limits["used"] * WORKER_MB <= max(limits["available_mb"], WORKER_MB)
    assert worker_limits(1)["used"] == 1
    assert worker_limits(cores, worker_mb=1e12)["used"] == 1  # never none
    task, policy = toy_configs()
    with caplog.at_level(logging.WARNING, logger="grt.evaluators.pool"):
        pool = WorkerPool(task, policy, workers=10_000)  # nothing is started before run()
    assert pool.num_workers == limits["used"] and pool.workers == []
    assert f"workers=10000: starting {limits['used']} simulator workers" in caplog.text
    assert f"{cores} CPU cores" in caplog.text and f"~{WORKER_MB} MB per worker" in caplog.text


KILLED_PARENT = """
import os, signal, sys
sys.path.insert(0, {here!r})
from grt.evaluators.pool import WorkerPool
pool = WorkerPool({{"name": "toy", "session": {{"_target_": "_toy_session.ToySession"}}}},
                  {{"_target_": "_toy_session.ToyPolicy"}}, workers=1)
pool.start()
assert pool.workers[0].conn.recv()[0] == "ready"
print(pool.workers[0].proc.pid, flush=True)
os.kill(os.getpid(), signal.SIGKILL)
"""


def test_workers_stop_quietly_when_their_parent_is_killed():
    """Issue 30 (9): a worker whose parent died without closing it (SIGKILL, SIGTERM's default) ends without
    a traceback (it printed ``EOFError`` from its pipe before)."""
    proc = subprocess.Popen([sys.executable, "-c", KILLED_PARENT.format(here=str(HERE))], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = proc.communicate(timeout=120)  # returns once the worker, which shares the pipes, is gone too
    assert proc.returncode == -signal.SIGKILL, err[-3000:]
    stat = Path(f"/proc/{int(out.split()[0])}/stat")
    assert not stat.exists() or stat.read_text().rsplit(")", 1)[1].split()[0] == "Z"  # gone (or not yet reaped)
    assert "Traceback" not in err and "EOFError" not in err, err[-3000:]
