"""Simulator worker processes: each builds its task session once and runs (candidate, seeds) jobs.

One process per worker (the ManiSkill CPU backend holds one environment per process), started with
``spawn`` (or ``forkserver``): nothing of the parent's simulator state leaks into a worker. Each
worker talks to the parent over its own pipe, so a worker that dies mid-message breaks only its own
channel. The parent (:class:`WorkerPool`) hands out jobs, collects one message per trial, and when a
worker dies (segfault, ``os._exit``, OOM kill) or hangs past ``trial_timeout`` it restarts the worker
and re-runs the seeds that had not finished; a seed that kills its worker more than ``max_retries``
times becomes a ``sim_error`` outcome.

A policy served from another process (:mod:`grt.policies.remote`) adds two events that are no trial's
fault: its connection broke mid-trial (:class:`~grt.policies.base.PolicyInterrupted`: the worker
re-runs that trial from its start, up to :data:`MAX_INTERRUPTIONS` times), or its server stayed down
(:class:`~grt.policies.base.PolicyUnavailable`): the worker says so and the pool stops the evaluation
with a :class:`~grt.policies.base.PolicyServerError` (one line; a red-team run is finished later with
``resume=DIR``).
"""

from __future__ import annotations

import contextlib
import gc
import logging
import multiprocessing as mp
import os
import signal
import socket
import sys
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection, wait
from pathlib import Path

import numpy as np
import trimesh

from grt.evaluators.base import Job, OnTrial, TrialPool, is_stock, sim_error
from grt.evaluators.worker_env import WorkerPathError, accept_numpy2_pickles, spawn_path, worker_path
from grt.policies.base import PolicyInterrupted, PolicyServerError, PolicyUnavailable
from grt.targets import instantiate, worker_error
from grt.tasks.base import TrialOutcome

__all__ = ["Job", "WorkerPool", "build_session", "prepare_job", "run_seed", "sim_error", "worker_limits"]

log = logging.getLogger(__name__)
#: re-runs of one trial whose policy connection broke, before the policy counts as unavailable
MAX_INTERRUPTIONS = 3


def build_session(task: dict, policy: dict):
    """Instantiate ``task["session"]`` with the instantiated ``policy`` (plain dicts, Hydra style)."""
    return instantiate(task["session"], policy=instantiate(policy), _convert_="all")


# ------------------------------------------------------------------------------------ worker side
def worker_main(task: dict, policy: dict, conn: Connection, threads: int | None = None) -> None:
    """Worker process entry: build the session, then run jobs until told to stop (``None``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to report; it stops us
    # ... and so is a scheduler's warning before its time limit: SLURM signals every process of the job step
    # (submitit's --signal=USR2@120, conf/hydra/launcher/slurm.yaml), whose default action would kill us
    signal.signal(signal.SIGUSR2, signal.SIG_IGN)
    accept_numpy2_pickles()  # a policy's own numpy 1.x (worker_path) reads the parent's jobs
    try:
        session = build_session(task, policy)
    except BaseException as exc:
        down = _policy_down(exc)
        conn.send(("unavailable", down) if down else ("fatal", traceback.format_exc()))
        return
    if threads and "torch" in sys.modules:  # torch also reads OMP_NUM_THREADS; make sure
        sys.modules["torch"].set_num_threads(threads)
    gc.collect()
    gc.freeze()  # ManiSkill's reconfigure runs gc.collect(): keep the long-lived heap out of it
    conn.send(("ready", None))
    using = {"key": None, "own": policy}  # key: the swapped-in policy (None: the pool's own)
    try:
        while (job := conn.recv()) is not None:
            _run_job(session, job, conn, using)
    except PolicyUnavailable as exc:
        conn.send(("unavailable", str(exc)))
    except (EOFError, OSError):  # the parent is gone (killed, or stopped without closing us): nobody to tell
        pass
    finally:
        session.close()


def _run_job(session, job: Job, conn: Connection, using: dict | None = None) -> None:
    mesh = job.mesh()
    start = time.perf_counter()  # the first trial's time includes loading the object
    load_error = prepare_job(session, mesh, job.parts, job.seeds, job.policy, using)
    conn.send(("loaded", job.job_id))
    for seed in job.seeds:
        outcome, load_error = run_seed(session, mesh, job.parts, int(seed), load_error, job.render_dir, job.candidate)
        now = time.perf_counter()
        conn.send(("trial", (job.job_id, int(seed), outcome, now - start)))
        start = now
    conn.send(("done", job.job_id))


def prepare_job(session, mesh: trimesh.Trimesh | None, parts: list[np.ndarray] | None, seeds: list[int], policy: dict | None,
                using: dict | None) -> str | None:
    """Make ``session`` ready for a job's trials: its policy (``using``: the worker's record of the policy it
    holds, see :func:`_use_policy`), the candidate's object (``None``: the task's stock object), the batched
    plans of its seeds.

    Returns:
        ``None``, or why the job's trials cannot run (each then becomes a ``sim_error``).
    """
    load_error = _use_policy(session, policy, using) if using is not None else None
    if load_error is None:
        load_error = _load(session, mesh, parts)
    if load_error is None and hasattr(session, "prefetch"):
        try:  # batched planning (a grasp network over several trials' clouds at once)
            session.prefetch(seeds)
        except Exception as exc:
            load_error = f"prefetch failed: {type(exc).__name__}: {exc}"
    return load_error


def run_seed(session, mesh: trimesh.Trimesh | None, parts: list[np.ndarray] | None, seed: int, load_error: str | None,
             render_dir: str | None, candidate: int) -> tuple[TrialOutcome, str | None]:
    """One trial of a prepared job (:func:`prepare_job`): its outcome (a ``sim_error`` when the job could
    not be prepared or the trial raised), and the job's load error after it (a failed trial rebuilds the
    object; that can fail too).

    Raises:
        PolicyUnavailable: the policy's server stayed down (the whole evaluation stops).
    """
    if load_error is not None:
        return sim_error(seed, load_error), load_error
    try:
        outcome = _run_trial(session, seed, lambda: _load(session, mesh, parts))
    except Exception as exc:
        outcome = sim_error(seed, f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(limit=8))
        # The session's state is unknown after a failure: rebuild the object before going on.
        return outcome, _load(session, mesh, parts)
    _render(session, render_dir, candidate, seed)
    return outcome, None


def _run_trial(session, seed: int, reload: Callable[[], str | None]) -> TrialOutcome:
    """One trial, re-run from its start when the policy's connection broke in it (the policy's episode
    state is gone; the scene is rebuilt, as after any failure).

    Raises:
        PolicyUnavailable: interrupted :data:`MAX_INTERRUPTIONS` times in a row.
    """
    for _ in range(MAX_INTERRUPTIONS):
        try:
            return session.run_trial(seed)
        except PolicyInterrupted as exc:
            log.warning("seed %d: %s; re-running the trial", seed, exc)
            why = exc
            if (error := reload()) is not None:
                raise RuntimeError(error) from None
    raise PolicyUnavailable(f"trial {seed} interrupted {MAX_INTERRUPTIONS} times in a row: {why}")


def _policy_down(exc: BaseException) -> str | None:
    """The message of a policy server that cannot be reached behind ``exc`` (Hydra wraps errors), or ``None``."""
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, PolicyServerError | PolicyUnavailable):
            return str(exc)
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


def _use_policy(session, policy: dict | None, using: dict) -> str | None:
    """Give the session the job's policy when it differs from the one it has (by config, and by the
    checkpoint file's modification time: a file rewritten in place is a new policy); a job without
    one gets the pool's own policy back."""
    if policy is None:
        if using["key"] is None:
            return None
        policy = using["own"]

    ckpt = policy.get("checkpoint")
    stamp = os.stat(ckpt).st_mtime_ns if isinstance(ckpt, str) and os.path.exists(ckpt) else None
    key = (repr(sorted(policy.items())), stamp)
    if key == using["key"]:
        return None
    try:
        made = instantiate(policy)
        if hasattr(session, "set_policy"):
            session.set_policy(made)
        else:
            session.policy = made
    except Exception as exc:
        using["key"] = "failed"  # whatever the session holds now, the next job sets it again
        return f"policy failed: {type(exc).__name__}: {exc}"
    using["key"] = None if policy is using["own"] else key
    return None


def _load(session, mesh: trimesh.Trimesh | None, parts: list[np.ndarray] | None) -> str | None:
    try:
        if mesh is not None and is_stock(mesh):  # the swap check: the task's own stock actor, not a mesh
            session.load_object(None, None)
        else:
            session.load_object(mesh, parts)
    except Exception as exc:
        return f"load_object failed: {type(exc).__name__}: {exc}"
    return None


def _render(session, render_dir: str | None, candidate: int, seed: int) -> None:
    render = getattr(session, "render", None)
    if render_dir is None or not callable(render):
        return
    path = Path(render_dir) / f"candidate{candidate:03d}_seed{seed}.png"
    try:
        render(str(path))
    except Exception as exc:  # a picture is a nicety: never lose a trial to it
        log.warning("rendering %s failed: %s", path, exc)


# ------------------------------------------------------------------------------------ parent side
def blame_first_seed(job: Job, crashes: dict, max_retries: int, on_trial, pending: deque, what: str, then: str,
                     error: str) -> None:
    """A worker died running ``job``: count the death against its first unfinished seed (a ``sim_error``
    once it passed ``max_retries``) and put the job's remaining seeds back at the front of ``pending``.
    Shared by the process pool and :class:`grt.evaluators.ray_pool.RayPool`."""
    key = (job.candidate, job.seeds[0])
    crashes[key] = crashes.get(key, 0) + 1
    log.warning("%s on candidate %d seed %d; %s", what, *key, then)
    if crashes[key] > max_retries:
        seed = job.seeds.pop(0)
        on_trial(job, sim_error(seed, f"{error}, {crashes[key]} times"), 0.0)
    if job.seeds:
        pending.appendleft(job)


# Memory of one worker once its session is built (RSS, MB; the largest of the tasks measured with
# scripts/worker_memory.py: 614-744 MB; see docs/benchmarks.md "Worker memory"), rounded up.
WORKER_MB = 800


def worker_limits(requested: int, worker_mb: float = WORKER_MB) -> dict:
    """How many workers this machine can run: ``requested`` bounded by the CPU cores this process may use
    and by the memory available (``MemAvailable``) over ``worker_mb``; at least one.

    Returns ``{"requested", "used", "cores", "available_mb", "worker_mb"}`` (``available_mb`` ``None`` where
    the system does not say).
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    available = _available_mb()
    used = min(int(requested), cores)
    if available is not None:
        used = min(used, int(available // worker_mb))
    return {"requested": int(requested), "used": max(1, used), "cores": cores,
            "available_mb": None if available is None else round(available), "worker_mb": worker_mb}


def _available_mb() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "LP_NUM_THREADS")


@contextlib.contextmanager
def _thread_limits(threads: int | None):
    """Environment a spawned worker starts with: thread-pool sizes read when its libraries load."""
    if not threads:
        yield
        return
    saved = {k: os.environ.get(k) for k in THREAD_VARIABLES}
    os.environ.update({k: str(threads) for k in THREAD_VARIABLES})
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v

@dataclass
class _Worker:
    proc: mp.process.BaseProcess
    conn: Connection
    ready: bool = False
    job: Job | None = None
    last_message: float = field(default_factory=time.monotonic)
    loaded: bool = False  # its job's object is loaded and its trials planned (the worker said "loaded")


def _reset_foreign_start_method() -> None:
    """Make spawned children loadable when a launcher installed its own start method.

    A spawned child re-applies the parent's *global* start method; under Hydra's joblib launcher that
    is loky's ``"loky"``, unknown to a plain Python child, which then dies before running a trial.
    """
    method = mp.get_start_method(allow_none=True)
    if method is not None and method not in ("fork", "spawn", "forkserver"):
        mp.set_start_method("spawn", force=True)


class WorkerPool(TrialPool):
    """Worker processes that each hold one task session (``evaluator=sim``'s :class:`~grt.evaluators.base.TrialPool`).

    Args:
        task: task config as a plain dict (``task["session"]`` is instantiated in each worker).
        policy: policy config as a plain dict.
        workers: number of processes.
        start_method: ``"spawn"`` or ``"forkserver"`` (``fork`` would copy simulator state).
        max_retries: re-runs of a seed whose worker died, before it becomes ``sim_error``.
        trial_timeout: seconds without any message from a busy worker before it is killed (a hang); while it
            loads a job (which may plan every trial of the job first) that many seconds per trial of the job.
        startup_timeout: seconds a worker may take to build its session.
        threads: CPU threads per worker for BLAS/OpenMP, torch and the lavapipe renderer (``None``:
            the libraries' defaults). Workers already fill the cores; more threads only contend.

    A policy config with ``worker_path`` (:mod:`grt.evaluators.worker_env`) gets workers that start with those
    folders first on their import path (``spawn`` only: a ``forkserver`` child is forked from a server that
    has imported its libraries already).

    More workers than the cores this process may use, or than the available memory holds at
    :data:`WORKER_MB` each, are not started: the pool warns with the numbers and runs as many as fit
    (``limits``, see :func:`worker_limits`); results do not depend on the number of workers.
    """

    def __init__(self, task: dict, policy: dict, workers: int = 2, start_method: str = "spawn",
                 max_retries: int = 2, trial_timeout: float | None = 600.0, startup_timeout: float = 300.0,
                 threads: int | None = 1):
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if start_method not in ("spawn", "forkserver"):
            raise ValueError(f"start_method must be 'spawn' or 'forkserver', got {start_method!r}")
        self.task, self.policy = task, policy
        self.path = worker_path(policy)
        if self.path and start_method != "spawn":
            raise WorkerPathError(f"evaluator.start_method={start_method}: the policy's workers start with their "
                                  f"own {', '.join(self.path)} first on their path, which only a spawned worker "
                                  "takes; set evaluator.start_method=spawn")
        self.limits = worker_limits(workers)
        if self.limits["used"] < workers:
            free = self.limits["available_mb"]
            log.warning("workers=%d: starting %d simulator workers, as many as this machine holds (%d CPU cores "
                        "for this process, %s memory available, ~%d MB per worker); results do not depend on the "
                        "number of workers", workers, self.limits["used"], self.limits["cores"],
                        "unknown" if free is None else f"{free / 1024:.1f} GB", self.limits["worker_mb"])
        self.num_workers, self.max_retries = self.limits["used"], int(max_retries)
        self.trial_timeout, self.startup_timeout = trial_timeout, startup_timeout
        _reset_foreign_start_method()
        self.ctx = mp.get_context(start_method)
        self.threads = int(threads) if threads else None
        self.workers: list[_Worker] = []
        self.restarts = 0  # workers replaced (crashed, hung or failed to start)
        self.trials = 0  # trials run (outcomes received), over every run()
        self.startup_failures = 0

    def _spawn(self) -> _Worker:
        parent, child = self.ctx.Pipe(duplex=True)
        proc = self.ctx.Process(target=worker_main, args=(self.task, self.policy, child, self.threads),
                                daemon=True)
        with _thread_limits(self.threads), spawn_path(self.path):
            proc.start()
        child.close()
        return _Worker(proc, parent)

    def start(self) -> None:
        """Start the missing workers (each builds its session in parallel with the others)."""
        while len(self.workers) < self.num_workers:
            self.workers.append(self._spawn())

    def run(self, jobs: deque[Job] | list[Job], on_trial: OnTrial) -> None:
        """Run every job's seeds; ``on_trial(job, outcome, seconds)`` once per seed, in any order. A ``deque`` of jobs is
        the pool's queue itself: ``on_trial`` may add jobs to it (racing: a candidate's next round).

        Raises:
            grt.targets.ClassError: a worker cannot build its session (one line; the traceback in a file).
        """
        self.start()
        pending, crashes = jobs if isinstance(jobs, deque) else deque(jobs), {}
        while pending or any(w.job is not None for w in self.workers):
            self._assign(pending)
            self._poll(on_trial, pending, crashes)

    @property
    def all_ready(self) -> bool:
        """Whether every worker is running and has built its session."""
        return len(self.workers) == self.num_workers and all(w.ready for w in self.workers)

    def info(self) -> dict:
        """The ``evaluator`` block of ``summary.json``: one node (this machine), its workers and their trials."""
        return {"backend": "pool", "address": None, "nodes": 1, "actors": self.num_workers,
                "trials_per_node": {socket.gethostname(): self.trials} if self.trials else {},
                "workers_replaced": self.restarts, "trial_timeout": self.trial_timeout}

    def wait_ready(self) -> None:
        """Start the workers and return once every one has built its session (what a progress bar's
        clock should not count).

        Raises:
            grt.targets.ClassError: a worker cannot build its task session (one line; the traceback in a file).
        """
        self.start()
        while not all(w.ready for w in self.workers):
            self._poll(lambda *_: None, deque(), {})

    def _poll(self, on_trial, pending: deque, crashes: dict) -> None:
        """Wait up to a second for messages and handle them; kill and replace a worker that stays quiet past its timeout."""
        ready = wait([w.conn for w in self.workers] + [w.proc.sentinel for w in self.workers], timeout=1.0)
        for w in list(self.workers):
            if w.conn in ready or w.proc.sentinel in ready:
                self._drain(w, on_trial, pending, crashes)
            elif self._timed_out(w):
                log.warning("worker %d silent for too long: killing it", w.proc.pid)
                w.proc.kill()
                w.proc.join()
                self._replace(w, on_trial, pending, crashes, "timed out (hung)")

    def _assign(self, pending: deque) -> None:
        for w in self.workers:
            if w.ready and w.job is None and pending:
                w.job, w.loaded = pending.popleft(), False
                w.last_message = time.monotonic()
                # A worker that died while idle is noticed through its sentinel; the job is re-queued.
                with contextlib.suppress(OSError):
                    w.conn.send(w.job)

    def _timed_out(self, w: _Worker) -> bool:
        if w.ready and w.job is None:  # idle: nothing to wait for
            return False
        limit = self.trial_timeout if w.ready else self.startup_timeout
        if limit is not None and w.ready and not w.loaded and w.job is not None:
            limit *= max(1, len(w.job.seeds))  # loading a job may plan all its trials first (batched planners)
        return limit is not None and time.monotonic() - w.last_message > limit

    def _drain(self, w: _Worker, on_trial, pending: deque, crashes: dict) -> None:
        while True:
            try:
                if not w.conn.poll():
                    break
                msg = w.conn.recv()
            except (EOFError, OSError):  # its end of the pipe closed: the process is exiting
                w.proc.join(timeout=5.0)
                if w.proc.is_alive():
                    w.proc.kill()
                    w.proc.join()
                break
            # outside the try: an error of on_trial (a journal that cannot be written) is the caller's, not a
            # dead worker's (it was once taken for one, and the candidate's result silently lost)
            self._handle(w, msg, on_trial)
        if not w.proc.is_alive():
            w.proc.join()
            self._replace(w, on_trial, pending, crashes, f"died (exit code {w.proc.exitcode})")

    def _handle(self, w: _Worker, msg: tuple, on_trial) -> None:
        kind, payload = msg
        w.last_message = time.monotonic()
        if kind == "fatal":
            self.close()
            raise worker_error("task.session", str(self.task["session"].get("_target_")), payload)
        if kind == "unavailable":
            self.close()
            raise PolicyServerError(f"{payload}; the evaluation stopped (nothing of its unfinished trials "
                                    "was recorded)")
        if kind == "ready":
            w.ready = True
        elif kind == "loaded":
            w.loaded = True
        elif kind == "trial" and w.job is not None:
            _job_id, seed, outcome, seconds = payload
            w.job.seeds.remove(seed)
            self.trials += 1
            on_trial(w.job, outcome, seconds)
        elif kind == "done":
            w.job = None

    def _replace(self, w: _Worker, on_trial, pending: deque, crashes: dict, why: str) -> None:
        """Restart a dead worker; blame its current seed, re-queue the rest of its job."""
        job, self.restarts = w.job, self.restarts + 1
        w.conn.close()
        if job is None and not w.ready:
            self.startup_failures += 1
            if self.startup_failures > self.num_workers * (self.max_retries + 1):
                self.close()
                raise RuntimeError(f"evaluator workers keep dying while starting: last one {why}")
        elif job is not None and job.seeds:
            blame_first_seed(job, crashes, self.max_retries, on_trial, pending, f"worker {why}", "restarting it",
                             f"worker process {why}")
        self.workers[self.workers.index(w)] = self._spawn()

    def close(self) -> None:
        """Stop every worker (politely, then by force)."""
        for w in self.workers:
            with contextlib.suppress(OSError):
                w.conn.send(None)
        for w in self.workers:
            w.proc.join(timeout=10)
            if w.proc.is_alive():
                w.proc.kill()
                w.proc.join()
            w.conn.close()
        self.workers = []
