"""SimEvaluator: candidate meshes -> convex parts -> seeded trials in worker processes -> scores.

Per :meth:`SimEvaluator.evaluate` call: every candidate gets its collision parts (the nominal
decomposition transported through the deformation, or CoACD, see :mod:`grt.evaluators.collision`), then
its trials are split into chunks of consecutive seeds, one chunk per job, so that even one candidate
keeps every worker busy; a worker loads a candidate's object once per chunk. Every candidate runs
the same seeds (common random numbers), and a trial's outcome depends only on (mesh, seed), so the
results do not depend on the number of workers or on the order in which jobs finish.
"""

from __future__ import annotations

import logging
import math
import socket
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from grt.console import progress as progress_bar
from grt.evaluators.base import CandidateResult, Evaluator
from grt.evaluators.collision import MAX_HULL_VERTICES, CollisionError, make_collision, mesh_label
from grt.evaluators.pool import Job, WorkerPool, sim_error
from grt.tasks import session_class
from grt.tasks.base import FALLBACK_TRIAL_TIMEOUT, SIM_ERROR, TRIAL_TIMEOUT_MARGIN, TrialOutcome

log = logging.getLogger(__name__)


def default_trial_timeout(task: dict, policy: dict | None) -> float:
    """``evaluator.trial_timeout=auto``: :data:`~grt.tasks.base.TRIAL_TIMEOUT_MARGIN` times the longest one trial
    of the task takes (:meth:`grt.tasks.base.TaskSession.trial_seconds`: its episode length at measured
    worst-case step times). :data:`~grt.tasks.base.FALLBACK_TRIAL_TIMEOUT` for a task that gives no bound (a
    user's, unless its session says), and at least that for a served policy: how long its replies take is the
    server's (each is bounded by ``policy.timeout`` in the worker, where a stalled server is caught).
    """
    try:
        cls = session_class(task)
    except Exception:  # noqa: BLE001 - a module only the workers import (a cluster's): no bound to read here
        return FALLBACK_TRIAL_TIMEOUT
    seconds = cls.trial_seconds(**{k: v for k, v in task["session"].items() if k != "_target_"})
    if seconds is None:
        return FALLBACK_TRIAL_TIMEOUT
    derived = round(TRIAL_TIMEOUT_MARGIN * seconds, 1)
    served = str((policy or {}).get("_target_", "")).startswith("grt.policies.remote.")
    return max(derived, FALLBACK_TRIAL_TIMEOUT) if served else derived


class SimEvaluator(Evaluator):
    """Score candidate meshes by simulated trials of a policy in worker processes.

    Args:
        task: task config as a plain dict; ``task["session"]`` (a Hydra node with ``_target_``)
            builds the :class:`grt.tasks.base.TaskSession` in each worker, with ``policy=``.
        policy: policy config as a plain dict (Hydra node with ``_target_``).
        workers: worker processes (one simulator each).
        collision: ``"fast"`` (transport the nominal CoACD decomposition; needs ``nominal``) or
            ``"coacd"`` (CoACD per candidate, cached by content).
        nominal: the nominal mesh (meters), for ``collision="fast"``.
        coacd: :class:`grt.evaluators.collision.CoacdParams` fields to override.
        cache_dir: CoACD cache folder (``None``: ``$GRT_CACHE_DIR/coacd`` or ``~/.cache/grt/coacd``).
        max_hull_vertices: cap on each convex part's vertex count (64: GPU PhysX).
        chunk_size: trials per job; ``None`` splits each candidate's seeds over the workers.
        max_retries: re-runs of a seed whose worker process died, before it is a ``sim_error``.
        trial_timeout: seconds a worker running a trial may stay silent before it is deemed hung and restarted;
            ``"auto"`` (the default): the task's own, from its episode length (:func:`default_trial_timeout`);
            ``None``: never.
        start_method: ``"spawn"`` or ``"forkserver"``.
        threads: CPU threads per worker (BLAS/OpenMP, torch, lavapipe); ``None``: library defaults.
        progress: show the trials' progress (a tqdm bar on a terminal, plain lines in a log: :mod:`grt.console`).
        render_dir: write one picture per trial there when the session has ``render(path)``.
    """

    races = True

    def __init__(self, task: dict, policy: dict, workers: int = 2, collision: str = "fast",
                 nominal: trimesh.Trimesh | None = None, coacd: dict | None = None,
                 cache_dir: str | None = None, max_hull_vertices: int = MAX_HULL_VERTICES,
                 chunk_size: int | None = None, max_retries: int = 2, trial_timeout: float | str | None = "auto",
                 start_method: str = "spawn", threads: int | None = 1, progress: bool = True,
                 render_dir: str | None = None):
        if not isinstance(task, dict) or "session" not in task:
            raise ValueError("task must be a plain dict with a 'session' node (OmegaConf.to_container it)")
        if not isinstance(policy, dict):
            raise ValueError("policy must be a plain dict (OmegaConf.to_container it)")
        if chunk_size is not None and chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1 or None, got {chunk_size}")
        if trial_timeout == "auto":
            trial_timeout = default_trial_timeout(task, policy)
        elif trial_timeout is not None and not float(trial_timeout) > 0:
            raise ValueError(f"evaluator.trial_timeout={trial_timeout}: give seconds > 0, auto (the task's own) or "
                             "null (never)")
        self.trial_timeout = trial_timeout
        self.collision = make_collision(collision, nominal, coacd, cache_dir, max_hull_vertices)
        self.collision_kind = collision
        self.pool = self._make_pool(task, policy, workers, start_method, max_retries, trial_timeout, threads)
        self.workers, self.chunk_size, self.progress = self.pool.num_workers, chunk_size, progress
        self.worker_limits = self.pool.limits  # requested and used workers, cores, memory (summary.json)
        self.render_dir = str(render_dir) if render_dir else None
        self.collision_s = 0.0
        self.run_s = 0.0  # seconds of the last evaluate's trials (the time its progress bar measures)

    def _make_pool(self, task, policy, workers, start_method, max_retries, trial_timeout, threads):
        """The workers: processes on this machine (``evaluator=ray``: actors, :mod:`grt.evaluators.ray_pool`)."""
        return WorkerPool(task, policy, workers, start_method, max_retries, trial_timeout, threads=threads)

    def backend_info(self) -> dict:
        """The ``evaluator`` block of ``summary.json``: where the trials ran."""
        host = socket.gethostname()
        return {"backend": "pool", "address": None, "nodes": 1, "actors": self.workers,
                "trials_per_node": {host: self.pool.trials} if self.pool.trials else {},
                "workers_replaced": self.pool.restarts, "trial_timeout": self.trial_timeout}

    # ------------------------------------------------------------------------------- interface
    def start(self, say=lambda line: print(line, flush=True)) -> float:
        """Start the simulator workers and wait until each has built its session; returns the seconds.

        ``say`` gets one line before (``starting N simulator workers ...``) and one after, so a command
        shows why nothing moves for the 10-30 s a simulator takes to start (``None``: silent). Starting
        first keeps that time out of the progress bar's rate and ETA; :meth:`evaluate` starts the workers
        itself otherwise.
        """
        if self.pool.all_ready:  # already up: nothing to wait for, nothing to say
            return 0.0
        begin = time.perf_counter()
        if say is not None:
            say(f"starting {self.workers} simulator worker{'s' * (self.workers != 1)} (each builds its own "
                "simulator and policy; this takes a while) ...")
        self.pool.wait_ready()
        seconds = time.perf_counter() - begin
        if say is not None:
            say(f"{self.workers} simulator worker{'s' * (self.workers != 1)} ready in {seconds:.1f} s")
        return seconds

    def evaluate(self, meshes: list[trimesh.Trimesh], seeds: list[int],
                 parts: list[list[np.ndarray]] | None = None, policy: dict | None = None,
                 on_result: Callable[[int, CandidateResult], None] | None = None, race=None) -> list[CandidateResult]:
        """Score every mesh on the same seeds; see :meth:`grt.evaluators.base.Evaluator.evaluate`.

        ``parts`` gives each mesh's convex parts when the caller already has them (else they are made).
        ``policy``: another policy config to score with on the same workers (e.g. each checkpoint of a
        fine-tune in turn; the workers keep their simulator and swap only the policy).
        ``on_result(i, result)``: called as soon as mesh ``i``'s trials are all in, while the others run.
        Every mesh's trials go to the workers together (the first mesh's first), so a call of several
        meshes keeps up to ``len(meshes) x len(seeds)`` workers busy.
        ``race`` (:class:`grt.racing.Race`, ``budget.racing``): each mesh's seeds run in rounds, in order,
        the rounds ending at ``race.at``; after each, ``race.stop(scores, errors)`` may stop the mesh (its
        result then holds the trials run and ``info["race"]``), which frees its workers for the next round's
        or the next mesh's seeds. A verdict depends only on the mesh's own trials, never on timing.
        """
        seeds = [int(s) for s in seeds]
        if not seeds:
            raise ValueError("seeds is empty: give at least one episode seed")
        if len(set(seeds)) != len(seeds):
            raise ValueError("seeds must be distinct (a repeated seed repeats the same episode)")
        if parts is not None and len(parts) != len(meshes):
            raise ValueError(f"parts must give one list per mesh ({len(meshes)}), got {len(parts)}")
        parts, errors = self._collision_parts(meshes) if parts is None else (list(parts), {})
        ends = [*race.at, len(seeds)] if race is not None else [len(seeds)]  # where each round ends
        jobs = self._jobs(meshes, parts, seeds[:ends[0]], policy, self.chunk_size if race is None else None)
        trials: list[dict[int, TrialOutcome]] = [{} for _ in meshes]
        wall = np.zeros(len(meshes))
        results: list[CandidateResult | None] = [None] * len(meshes)
        rounds = [0] * len(meshes)

        def finish(i: int, n: int, verdict: dict | None = None) -> None:
            info = {"collision": self.collision_kind, "parts": len(parts[i])}
            if race is not None:
                info["race"] = {"trials": n, "of": len(seeds), **(verdict or {"stopped": None})}
            results[i] = CandidateResult.from_trials([trials[i][s] for s in seeds[:n]], wall[i], info)
            if on_result is not None:
                on_result(i, results[i])

        for i, reason in errors.items():
            trials[i] = {s: sim_error(s, reason) for s in seeds}
            finish(i, len(seeds))
        bar = self._progress_bar(len(meshes) * len(seeds) if race is not None else sum(len(j.seeds) for j in jobs))
        pending = deque(jobs)

        def on_trial(job: Job, outcome: TrialOutcome, seconds: float) -> None:
            i = job.candidate
            trials[i][outcome.seed] = outcome
            wall[i] += seconds
            if bar is not None:
                bar.update(1)
            if results[i] is not None or len(trials[i]) != ends[rounds[i]]:
                return
            n = ends[rounds[i]]
            verdict = None
            if n < len(seeds):
                ran = [trials[i][s] for s in seeds[:n]]
                verdict = race.stop([t.score for t in ran if t.mode != SIM_ERROR],
                                    errors=sum(t.mode == SIM_ERROR for t in ran))
            if n == len(seeds) or verdict is not None:
                finish(i, n, verdict)
                return
            rounds[i] += 1  # its next round goes first: earlier candidates finish (and are journaled) sooner
            more = self._jobs([meshes[i]], [parts[i]], seeds[n:ends[rounds[i]]], policy, None, first_id=self._ids)
            for j in more:
                j.candidate = i
            pending.extendleft(reversed(more))

        start = time.perf_counter()
        try:
            self.pool.run(pending, on_trial)
        finally:
            self.run_s = time.perf_counter() - start
            if bar is not None:
                bar.close()
        return results

    def evaluate_each(self, meshes: list[trimesh.Trimesh], seeds: list[int],
                      on_result: Callable[[int, CandidateResult], None], race=None) -> list[CandidateResult]:
        """:meth:`evaluate` with a call-back per mesh as its trials finish (the others still running)."""
        return self.evaluate(meshes, seeds, on_result=on_result, race=race)

    def collision_parts(self, mesh: trimesh.Trimesh) -> list[np.ndarray]:
        """The convex parts this evaluator simulates ``mesh`` with (cached, so cheap after evaluate)."""
        return self.collision.parts(mesh)

    def close(self) -> None:
        """Stop the worker processes."""
        self.pool.close()

    # -------------------------------------------------------------------------------- helpers
    def _collision_parts(self, meshes: list[trimesh.Trimesh]) -> tuple[list[list[np.ndarray]], dict[int, str]]:
        """Parts per mesh; a mesh whose decomposition fails gets no parts and an error reason."""
        start = time.perf_counter()
        parts, errors = [], {}
        for i, mesh in enumerate(meshes):
            try:
                parts.append(self.collision.parts(mesh))
            except (CollisionError, ValueError) as exc:
                log.warning("candidate %d (%s): %s", i, mesh_label(mesh), exc)
                parts.append([])
                errors[i] = f"collision geometry failed: {exc}"
        self.collision_s += time.perf_counter() - start
        return parts, errors

    def _jobs(self, meshes: list[trimesh.Trimesh], parts: list[list[np.ndarray]], seeds: list[int],
              policy: dict | None, chunk_size: int | None, first_id: int = 0) -> list[Job]:
        """Each mesh's ``seeds`` cut into jobs of ``chunk_size`` (``None``: spread over the workers)."""
        size = chunk_size or math.ceil(len(seeds) / self.workers)
        if self.render_dir:
            Path(self.render_dir).mkdir(parents=True, exist_ok=True)
        jobs = []
        for i, mesh in enumerate(meshes):
            if not parts[i]:
                continue
            meta = {k: v for k, v in mesh.metadata.items() if isinstance(v, str | int | float)}
            for lo in range(0, len(seeds), size):
                jobs.append(Job(first_id + len(jobs), i, np.asarray(mesh.vertices, np.float64),
                                np.asarray(mesh.faces), parts[i], list(seeds[lo:lo + size]), self.render_dir, meta,
                                policy))
        self._ids = first_id + len(jobs)  # job ids stay unique within one evaluate call
        return jobs

    def _progress_bar(self, total: int):
        if not self.progress or not total:
            return None
        return progress_bar(total, "trials", "trial", leave=False)
