"""SimEvaluator (``evaluator=sim``): seeded trials in worker processes on this machine.

The evaluator of :mod:`grt.evaluators.base` with a :class:`grt.evaluators.pool.WorkerPool`: every candidate
gets its collision parts (the nominal decomposition transported through the deformation, or CoACD, see
:mod:`grt.evaluators.collision`), then its trials are split into chunks of consecutive seeds, one chunk per
job, so that even one candidate keeps every worker busy; a worker loads a candidate's object once per chunk.
Every candidate runs the same seeds (common random numbers), and a trial's outcome depends only on
(mesh, seed), so the results do not depend on the number of workers or on the order in which jobs finish.
"""

from __future__ import annotations

import logging

import trimesh

from grt.evaluators.base import PoolEvaluator, TrialPool
from grt.evaluators.collision import MAX_HULL_VERTICES
from grt.evaluators.pool import WorkerPool
from grt.tasks import session_class
from grt.tasks.base import FALLBACK_TRIAL_TIMEOUT, TRIAL_TIMEOUT_MARGIN

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


class SimEvaluator(PoolEvaluator):
    """Score candidate meshes by simulated trials of a policy in worker processes on this machine.

    Args (besides :class:`~grt.evaluators.base.PoolEvaluator`'s):
        workers: worker processes (one simulator each).
        max_retries: re-runs of a seed whose worker process died, before it is a ``sim_error``.
        trial_timeout: seconds a worker running a trial may stay silent before it is deemed hung and restarted;
            ``"auto"`` (the default): the task's own, from its episode length (:func:`default_trial_timeout`);
            ``None``: never.
        start_method: ``"spawn"`` or ``"forkserver"``.
        threads: CPU threads per worker (BLAS/OpenMP, torch, lavapipe); ``None``: library defaults.
    """

    runs_stock = True  # the workers load a stock_actor() mesh as the stock actor (grt.evaluators.pool._load)

    def __init__(self, task: dict, policy: dict, workers: int = 2, collision: str = "fast",
                 nominal: trimesh.Trimesh | None = None, coacd: dict | None = None,
                 cache_dir: str | None = None, max_hull_vertices: int = MAX_HULL_VERTICES,
                 chunk_size: int | None = None, max_retries: int = 2, trial_timeout: float | str | None = "auto",
                 start_method: str = "spawn", threads: int | None = 1, progress: bool = True,
                 render_dir: str | None = None):
        if trial_timeout == "auto" and isinstance(task, dict) and "session" in task:
            trial_timeout = default_trial_timeout(task, policy)
        elif trial_timeout is not None and trial_timeout != "auto" and not float(trial_timeout) > 0:
            raise ValueError(f"evaluator.trial_timeout={trial_timeout}: give seconds > 0, auto (the task's own) or "
                             "null (never)")
        self.trial_timeout = trial_timeout
        self._pool_args = {"workers": workers, "start_method": start_method, "max_retries": max_retries,
                           "threads": threads}
        super().__init__(task, policy, nominal, collision, coacd, cache_dir, max_hull_vertices, chunk_size, progress,
                         render_dir)
        self.workers = self.pool.num_workers
        self.worker_limits = self.pool.limits  # requested and used workers, cores, memory (summary.json)

    def _make_pool(self) -> TrialPool:
        """The workers: processes on this machine (``evaluator=ray``: actors, :mod:`grt.evaluators.ray_pool`)."""
        a = self._pool_args
        return WorkerPool(self.task, self.policy, a["workers"], a["start_method"], a["max_retries"],
                          self.trial_timeout, threads=a["threads"])
