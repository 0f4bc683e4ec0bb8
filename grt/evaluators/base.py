"""Evaluator interface (candidate meshes in, one score per candidate out) and the one evaluator behind it.

Every candidate of one :meth:`Evaluator.evaluate` call is scored on the same episode seeds (common
random numbers, the paper's protocol): differences between candidates then come from their shapes,
not from the luck of the draw.

:class:`PoolEvaluator` does what every evaluator does alike: each candidate's collision parts, the seeds,
the jobs (a candidate's seeds, cut for the pool), racing (:mod:`grt.racing`: a candidate's seeds in rounds,
stopped once it cannot matter), and the results, each called back as soon as its trials are in. Where the
trials run is a :class:`TrialPool` behind one seam, ``run(jobs, on_trial)``: worker processes on this machine
(``evaluator=sim``, :mod:`grt.evaluators.pool`), Ray actors on a cluster (``evaluator=ray``,
:mod:`grt.evaluators.ray_pool`), or the parallel sub-scenes of one GPU simulation (``evaluator=gpu``,
:mod:`grt.evaluators.gpu`). So racing, confirmation and every later feature work on all three, and a trial's
outcome depends only on (mesh, seed), never on the pool or the order in which its jobs finish.
"""

from __future__ import annotations

import logging
import math
import time
from abc import ABC, abstractmethod
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from grt.console import progress as progress_bar
from grt.errors import UserError
from grt.evaluators.collision import MAX_HULL_VERTICES, CollisionError, make_collision, mesh_label
from grt.metrics import score_interval
from grt.targets import locate
from grt.tasks.base import SIM_ERROR, TrialOutcome, sim_error

log = logging.getLogger(__name__)


@dataclass
class CandidateResult:
    """The score of one candidate and the trials behind it.

    Attributes:
        score: the task metric averaged over the trials that ran (``sim_error`` trials excluded:
            a simulator failure says nothing about the policy); NaN when every trial errored.
        trials: one :class:`TrialOutcome` per seed, in the order of the seeds given.
        wall_s: seconds of worker time spent on this candidate (object loading + trials).
    """

    score: float
    trials: list[TrialOutcome]
    wall_s: float
    info: dict = field(default_factory=dict)

    @classmethod
    def from_trials(cls, trials: list[TrialOutcome], wall_s: float, info: dict | None = None) -> CandidateResult:
        """Build a result, computing ``score`` from the trials."""
        valid = [t.score for t in trials if t.mode != SIM_ERROR]
        score = float(np.mean(valid)) if valid else float("nan")
        return cls(score=score, trials=list(trials), wall_s=float(wall_s), info=dict(info or {}))

    @property
    def valid_trials(self) -> list[TrialOutcome]:
        """Trials that ran to an outcome (all but ``sim_error``)."""
        return [t for t in self.trials if t.mode != SIM_ERROR]

    @property
    def success_rate(self) -> float:
        """Fraction of valid trials that succeeded (NaN without valid trials)."""
        valid = self.valid_trials
        return sum(t.success for t in valid) / len(valid) if valid else float("nan")

    @property
    def outcomes(self) -> dict[str, int]:
        """Trial count per outcome mode (``success``, ``missed``, ..., ``sim_error``)."""
        return dict(Counter(t.mode for t in self.trials))

    @property
    def sim_errors(self) -> int:
        return sum(t.mode == SIM_ERROR for t in self.trials)

    def ci95(self, method: str = "auto") -> tuple[float, float]:
        """95% interval of ``score`` over the valid trials (NaN without any).

        Args:
            method: the task's ``ci`` setting: ``auto`` (Wilson when every trial scored 0 or 1, else
                the normal approximation), ``wilson``, ``normal`` or ``bootstrap``; see
                :func:`grt.metrics.score_interval`.
        """
        return score_interval([t.score for t in self.valid_trials], method)

    def summary(self, ci: str = "auto") -> dict:
        """JSON-ready figures: score, success_rate, trials, outcomes, ci95 (by ``ci``), wall_s."""
        low, high = self.ci95(ci)
        return {"score": self.score, "success_rate": self.success_rate, "trials": len(self.trials),
                "outcomes": self.outcomes, "ci95": [low, high], "wall_s": self.wall_s}


#: the metadata key of a mesh that stands for the task's stock actor (:func:`stock_actor`)
STOCK = "grt_stock"


def stock_actor(nominal: trimesh.Trimesh) -> trimesh.Trimesh:
    """A "candidate" that is the task's own stock actor (the swap check, :mod:`grt.swapcheck`): the nominal
    mesh marked so, which an evaluator with ``runs_stock`` loads as ``session.load_object(None, None)``."""
    return trimesh.Trimesh(nominal.vertices, nominal.faces, process=False,
                           metadata={STOCK: True, "name": "stock actor"})


def is_stock(mesh: trimesh.Trimesh) -> bool:
    """Whether ``mesh`` stands for the stock actor (:func:`stock_actor`)."""
    return bool(mesh.metadata.get(STOCK))


class NothingScoredError(UserError):
    """Every trial of an object ended in ``sim_error`` (a policy's unusable output, a simulator that cannot
    build the object...): it has no score, and nothing built on it (S0, a drop) could be trusted."""


def check_scored(result: CandidateResult, what: str) -> None:
    """Raise :class:`NothingScoredError` when every trial of ``result`` (of ``what``, e.g. "the nominal object")
    ended in ``sim_error``, naming the first trial's reason."""
    if not result.trials or result.sim_errors < len(result.trials):
        return
    first = next((t for t in result.trials if t.info.get("error")), result.trials[0])
    reason = str(first.info.get("error") or "no reason recorded").strip().splitlines()[0][:400]
    raise NothingScoredError(f"every trial on {what} ({len(result.trials)}) ended in sim_error, so it has no score; "
                             f"the first (seed {first.seed}): {reason}")


class Evaluator(ABC):
    """Scores candidate meshes by simulated trials of a policy. Use as a context manager."""

    #: Whether :meth:`evaluate_each` stops a candidate's trials early when given ``race`` (``budget.racing``);
    #: one that does not runs every trial, and a run that asked for racing says so.
    races = False
    #: Whether a :func:`stock_actor` mesh is run with the task's stock actor (the swap check); one that cannot
    #: leaves the check unrun, and the record says so.
    runs_stock = False

    @abstractmethod
    def evaluate(self, meshes: list[trimesh.Trimesh], seeds: list[int]) -> list[CandidateResult]:
        """Score every mesh on the same episode seeds.

        Args:
            meshes: candidate meshes in meters (z up, resting on z = 0, centered in x/y).
            seeds: episode seeds, the same for every candidate (common random numbers).

        Returns:
            One :class:`CandidateResult` per mesh, in order; its trials follow ``seeds``.
        """

    def evaluate_each(self, meshes: list[trimesh.Trimesh], seeds: list[int],
                      on_result: Callable[[int, CandidateResult], None], race=None) -> list[CandidateResult]:
        """:meth:`evaluate`, calling ``on_result(i, result)`` as soon as mesh ``i``'s trials are all in.

        The red-team loop scores a whole population in one call this way and journals each candidate
        as it finishes, so a killed run loses little. This default calls back after :meth:`evaluate`,
        in order; :class:`grt.evaluators.sim.SimEvaluator` calls back while the other meshes still run.
        ``race`` (:class:`grt.racing.Race`): stop a mesh's trials in rounds once it cannot matter
        (:class:`~grt.evaluators.sim.SimEvaluator` does); this default runs every trial, which is always
        correct (a full-trial result is what racing would have kept for a candidate that matters).
        """
        results = self.evaluate(meshes, seeds)
        for i, result in enumerate(results):
            on_result(i, result)
        return results

    @abstractmethod
    def collision_parts(self, mesh: trimesh.Trimesh) -> list[np.ndarray]:
        """The convex parts ``(K, 3)`` (meters) the simulator uses for ``mesh`` (saved with CrashShapes)."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release workers and simulators."""

    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def evaluator_preflight(evaluator: dict, task: dict, policy: dict) -> None:
    """Refuse, before a command writes anything, what the configured evaluator cannot run: the evaluator
    class's own ``preflight(task=, policy=, **its config)`` when it has one (``evaluator=gpu``: a task or a
    policy that cannot run batched, no CUDA); the CPU evaluators run every task and have none.

    Args:
        evaluator: the evaluator config as a plain dict (``_target_`` and its keys).
        task, policy: the task and policy configs as plain dicts.
    """
    check = getattr(locate(str(evaluator["_target_"]), "evaluator"), "preflight", None)
    if check is not None:
        check(task=task, policy=policy, **{k: v for k, v in evaluator.items() if not k.startswith("_")})


# ------------------------------------------------------------------------------------ the seam
@dataclass
class Job:
    """Trials of one candidate, for a pool to run.

    Attributes:
        job_id: unique within a :meth:`TrialPool.run` call.
        candidate: index of the candidate mesh.
        vertices: ``(V, 3)`` mesh vertices (m); faces: ``(F, 3)``; both ``None`` for the task's stock object.
        parts: convex collision parts, each ``(K, 3)`` (m); ``None`` for the stock object.
        seeds: the episode seeds still to run, in order.
        render_dir: folder for one picture per trial, or ``None``.
        policy: a policy config to run these trials with instead of the pool's own (``None``: the pool's);
            a worker re-instantiates it only when it or its checkpoint file changed.
    """

    job_id: int
    candidate: int
    vertices: np.ndarray | None
    faces: np.ndarray | None
    parts: list[np.ndarray] | None
    seeds: list[int]
    render_dir: str | None = None
    metadata: dict = field(default_factory=dict)
    policy: dict | None = None

    def mesh(self) -> trimesh.Trimesh | None:
        """The candidate's mesh (``None``: the task's stock object)."""
        return candidate_mesh(self.vertices, self.faces, self.metadata)


def candidate_mesh(vertices: np.ndarray | None, faces: np.ndarray | None, metadata: dict) -> trimesh.Trimesh | None:
    """A job's mesh as a simulator rebuilds it from the arrays it was sent (``None``: the stock object)."""
    if vertices is None:
        return None
    return trimesh.Trimesh(vertices, faces, process=False, metadata=dict(metadata))


OnTrial = Callable[[Job, TrialOutcome, float], None]


class TrialPool(ABC):
    """Where an evaluator's trials run. :meth:`run` takes a queue of jobs and calls ``on_trial(job, outcome,
    seconds)`` once per seed, in any order (``seconds``: the trial's share of the pool's time, the object's
    loading included); ``on_trial`` may add jobs to the queue while it runs (racing: a candidate's next
    round), and :meth:`run` returns once the queue is empty and every trial is in."""

    #: trials the pool runs at once (processes, actors); a candidate's seeds are cut into as many jobs
    num_workers: int = 1

    def job_size(self, seeds: int) -> int:
        """How many of a candidate's ``seeds`` one job holds: spread over the workers."""
        return max(1, math.ceil(seeds / self.num_workers))

    @abstractmethod
    def run(self, jobs: deque[Job], on_trial: OnTrial) -> None:
        """Run every job's seeds (see the class docstring)."""

    @property
    def all_ready(self) -> bool:
        """Whether the pool has started and its simulators are built."""
        return True

    def wait_ready(self) -> None:  # noqa: B027 - optional hook
        """Start the pool and return once every simulator is built."""

    @abstractmethod
    def info(self) -> dict:
        """The ``evaluator`` block of ``summary.json``: where and how the trials ran."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Stop the pool's processes and simulators."""


# ------------------------------------------------------------------------------------ the evaluator
class PoolEvaluator(Evaluator):
    """Score candidate meshes by simulated trials of a policy in a :class:`TrialPool` (the module docstring).

    A subclass stores its pool's settings and makes the pool in :meth:`_make_pool` (called once the collision
    settings are checked).

    Args:
        task: task config as a plain dict; ``task["session"]`` (a Hydra node with ``_target_``) builds the
            :class:`grt.tasks.base.TaskSession` the trials run in, with ``policy=``.
        policy: policy config as a plain dict (Hydra node with ``_target_``).
        nominal: the nominal mesh (meters), for ``collision="fast"``.
        collision: ``"fast"`` (transport the nominal CoACD decomposition; needs ``nominal``) or
            ``"coacd"`` (CoACD per candidate, cached by content).
        coacd: :class:`grt.evaluators.collision.CoacdParams` fields to override.
        cache_dir: CoACD cache folder (``None``: ``$GRT_CACHE_DIR/coacd`` or ``~/.cache/grt/coacd``).
        max_hull_vertices: cap on each convex part's vertex count (64: GPU PhysX).
        chunk_size: trials per job; ``None``: the pool's (:meth:`TrialPool.job_size`).
        progress: show the trials' progress (a tqdm bar on a terminal, plain lines in a log: :mod:`grt.console`).
        render_dir: write one picture per trial there when the session has ``render(path)``.
    """

    races = True
    #: what every result's ``info`` says of this evaluator (``evaluator=gpu``: ``{"evaluator": "gpu"}``)
    result_info: dict = {}

    def __init__(self, task: dict, policy: dict, nominal: trimesh.Trimesh | None = None, collision: str = "fast",
                 coacd: dict | None = None, cache_dir: str | None = None, max_hull_vertices: int = MAX_HULL_VERTICES,
                 chunk_size: int | None = None, progress: bool = True, render_dir: str | None = None):
        if not isinstance(task, dict) or "session" not in task:
            raise ValueError("task must be a plain dict with a 'session' node (OmegaConf.to_container it)")
        if not isinstance(policy, dict):
            raise ValueError("policy must be a plain dict (OmegaConf.to_container it)")
        self.task, self.policy = task, policy
        if chunk_size is not None and chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1 or None, got {chunk_size}")
        self.collision = make_collision(collision, nominal, coacd, cache_dir, max_hull_vertices)
        self.collision_kind, self.chunk_size, self.progress = collision, chunk_size, progress
        self.render_dir = str(render_dir) if render_dir else None
        self.collision_s = 0.0
        self.run_s = 0.0  # seconds of the last evaluate's trials (the time its progress bar measures)
        self._ids = 0
        self.pool: TrialPool = self._make_pool()

    @abstractmethod
    def _make_pool(self) -> TrialPool:
        """The pool the trials run in."""

    def backend_info(self) -> dict:
        """The ``evaluator`` block of ``summary.json``: where the trials ran (the pool's)."""
        return self.pool.info()

    def start(self, say=lambda line: print(line, flush=True)) -> float:
        """Start the pool and wait until its simulators are built; returns the seconds.

        ``say`` gets one line before (``starting N simulator workers ...``) and one after, so a command
        shows why nothing moves for the 10-30 s a simulator takes to start (``None``: silent). Starting
        first keeps that time out of the progress bar's rate and ETA; :meth:`evaluate` starts the pool
        itself otherwise.
        """
        if self.pool.all_ready:  # already up: nothing to wait for, nothing to say
            return 0.0
        begin, n = time.perf_counter(), self.pool.num_workers
        if say is not None:
            say(f"starting {n} simulator worker{'s' * (n != 1)} (each builds its own simulator and policy; this "
                "takes a while) ...")
        self.pool.wait_ready()
        seconds = time.perf_counter() - begin
        if say is not None:
            say(f"{n} simulator worker{'s' * (n != 1)} ready in {seconds:.1f} s")
        return seconds

    def evaluate(self, meshes: list[trimesh.Trimesh | None], seeds: list[int],
                 parts: list[list[np.ndarray]] | None = None, policy: dict | None = None,
                 on_result: Callable[[int, CandidateResult], None] | None = None, race=None) -> list[CandidateResult]:
        """Score every mesh on the same seeds; see :meth:`Evaluator.evaluate`.

        ``meshes``: a ``None`` is the task's stock object (a ManiSkill task's own actor).
        ``parts`` gives each mesh's convex parts when the caller already has them (else they are made).
        ``policy``: another policy config to score with on the same simulators (e.g. each checkpoint of a
        fine-tune in turn; the simulators stay, only the policy is swapped).
        ``on_result(i, result)``: called as soon as mesh ``i``'s trials are all in, while the others run.
        Every mesh's jobs go to the pool together (the first mesh's first).
        ``race`` (:class:`grt.racing.Race`, ``budget.racing``): each mesh's seeds run in rounds, in order,
        the rounds ending at ``race.at``; after each, ``race.stop(scores, errors)`` may stop the mesh (its
        result then holds the trials run and ``info["race"]``), which frees the pool for the next round's
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
        book = _Book(self, meshes, parts, seeds, policy, race, on_result)
        for i, reason in errors.items():
            book.fail(i, reason)
        self._ids = 0
        pending = deque(self._jobs(meshes, parts, seeds[:book.ends[0]], policy, None if race else self.chunk_size))
        total = len(meshes) * len(seeds) if race is not None else sum(len(j.seeds) for j in pending)
        book.bar = progress_bar(total, "trials", "trial", leave=False) if self.progress and total else None
        start = time.perf_counter()
        try:
            self.pool.run(pending, lambda job, outcome, seconds: pending.extendleft(
                reversed(book.on_trial(job, outcome, seconds))))
        finally:
            self.run_s = time.perf_counter() - start
            if book.bar is not None:
                book.bar.close()
        return book.results

    def evaluate_each(self, meshes: list[trimesh.Trimesh | None], seeds: list[int],
                      on_result: Callable[[int, CandidateResult], None], race=None) -> list[CandidateResult]:
        """:meth:`evaluate` with a call-back per mesh as its trials finish (the others still running)."""
        return self.evaluate(meshes, seeds, on_result=on_result, race=race)

    def collision_parts(self, mesh: trimesh.Trimesh) -> list[np.ndarray]:
        """The convex parts this evaluator simulates ``mesh`` with (cached, so cheap after evaluate)."""
        return self.collision.parts(mesh)

    def close(self) -> None:
        """Stop the pool."""
        self.pool.close()

    # -------------------------------------------------------------------------------- helpers
    def _collision_parts(self, meshes: list[trimesh.Trimesh | None]) -> tuple[list, dict[int, str]]:
        """Parts per mesh (``None`` for the stock object); a mesh whose decomposition fails gets no parts and an
        error reason."""
        start = time.perf_counter()
        parts, errors = [], {}
        for i, mesh in enumerate(meshes):
            try:
                parts.append(None if mesh is None else self.collision.parts(mesh))
            except (CollisionError, ValueError) as exc:
                log.warning("candidate %d (%s): %s", i, mesh_label(mesh), exc)
                parts.append([])
                errors[i] = f"collision geometry failed: {exc}"
        self.collision_s += time.perf_counter() - start
        return parts, errors

    def _jobs(self, meshes: list, parts: list, seeds: list[int], policy: dict | None, chunk_size: int | None,
              only: int | None = None) -> list[Job]:
        """Each mesh's ``seeds`` (``only``: mesh ``only``'s) cut into jobs of ``chunk_size`` (``None``: the pool's)."""
        size = chunk_size or self.pool.job_size(len(seeds))
        if self.render_dir:
            Path(self.render_dir).mkdir(parents=True, exist_ok=True)
        jobs = []
        for i, mesh in enumerate(meshes):
            if (only is not None and i != only) or (mesh is not None and not parts[i]):
                continue
            meta = {k: v for k, v in mesh.metadata.items() if isinstance(v, str | int | float)} if mesh else {}
            geometry = (None, None) if mesh is None else (np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces))
            for lo in range(0, len(seeds), size):
                jobs.append(Job(self._ids, i, *geometry, parts[i], list(seeds[lo:lo + size]), self.render_dir,
                                meta, policy))
                self._ids += 1  # job ids stay unique within one evaluate call
        return jobs


class _Book:
    """One :meth:`PoolEvaluator.evaluate` call's candidates: their trials as they come in, their racing rounds,
    and their results, each called back once complete."""

    def __init__(self, evaluator: PoolEvaluator, meshes: list, parts: list, seeds: list[int], policy: dict | None,
                 race, on_result):
        self.evaluator, self.meshes, self.parts, self.seeds = evaluator, meshes, parts, seeds
        self.policy, self.race, self.on_result = policy, race, on_result
        self.ends = [*race.at, len(seeds)] if race is not None else [len(seeds)]  # where each round ends
        self.trials: list[dict[int, TrialOutcome]] = [{} for _ in meshes]
        self.wall = np.zeros(len(meshes))
        self.results: list[CandidateResult | None] = [None] * len(meshes)
        self.rounds = [0] * len(meshes)
        self.bar = None

    def fail(self, i: int, reason: str) -> None:
        """Mesh ``i`` cannot be simulated (its collision geometry failed): every trial a ``sim_error``."""
        self.trials[i] = {s: sim_error(s, reason) for s in self.seeds}
        self.finish(i, len(self.seeds))

    def finish(self, i: int, n: int, verdict: dict | None = None) -> None:
        """Mesh ``i``'s result from its first ``n`` trials (racing: ``verdict``, why it stopped), called back."""
        info = {"collision": self.evaluator.collision_kind, "parts": len(self.parts[i] or []),
                **self.evaluator.result_info}
        if self.race is not None:
            info["race"] = {"trials": n, "of": len(self.seeds), **(verdict or {"stopped": None})}
        self.results[i] = CandidateResult.from_trials([self.trials[i][s] for s in self.seeds[:n]], self.wall[i], info)
        if self.on_result is not None:
            self.on_result(i, self.results[i])

    def on_trial(self, job: Job, outcome: TrialOutcome, seconds: float) -> list[Job]:
        """Record one trial; at the end of a mesh's round, finish it or return its next round's jobs."""
        i = job.candidate
        self.trials[i][outcome.seed] = outcome
        self.wall[i] += seconds
        if self.bar is not None:
            self.bar.update(1)
        if self.results[i] is not None or len(self.trials[i]) != self.ends[self.rounds[i]]:
            return []
        n = self.ends[self.rounds[i]]
        verdict = None
        if n < len(self.seeds):
            ran = [self.trials[i][s] for s in self.seeds[:n]]
            verdict = self.race.stop([t.score for t in ran if t.mode != SIM_ERROR],
                                     errors=sum(t.mode == SIM_ERROR for t in ran))
        if n == len(self.seeds) or verdict is not None:
            self.finish(i, n, verdict)
            return []
        self.rounds[i] += 1  # its next round goes first: earlier candidates finish (and are journaled) sooner
        return self.evaluator._jobs(self.meshes, self.parts, self.seeds[n:self.ends[self.rounds[i]]], self.policy,
                                    None, only=i)
