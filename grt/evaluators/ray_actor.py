"""The Ray actor of ``evaluator=ray``: one task session per actor, running a job's trials one call each.

This module imports nothing of GRT at its top and is sent to the cluster by value (see
:func:`grt.evaluators.ray_pool.actor_class`): on a node where GRT, or the task's own module, cannot be
imported, the actor still starts, and :meth:`SimActor.setup` says which node misses which module instead
of dying with a traceback nobody reads.

The calls a driver makes, in order (an actor runs its calls one at a time, in the order they were sent):
``setup()`` once, then per job ``load(...)`` and one ``trial(seed)`` per seed. A trial does what a pool
worker does for it (:func:`grt.evaluators.pool.run_seed`): the outcome depends only on (mesh, seed).
"""

from __future__ import annotations

import gc
import os
import re
import socket
import sys
import time
import traceback

_MISSING = re.compile(r"No module named '([^']+)'")


def _missing_module(exc: BaseException) -> str | None:
    """The module an import failure behind ``exc`` could not find (Hydra wraps it), or ``None``."""
    for _ in range(10):
        if exc is None:
            return None
        if isinstance(exc, ModuleNotFoundError) and exc.name:
            return exc.name
        if (found := _MISSING.search(str(exc))) is not None:
            return found.group(1)
        exc = exc.__cause__ or exc.__context__
    return None


class SimActor:
    """One simulator on a cluster node; see the module docstring.

    Args:
        task, policy: plain-dict configs (as :class:`grt.evaluators.pool.WorkerPool` takes them).
        threads: CPU threads for torch (the thread variables come with the actor's environment).
    """

    def __init__(self, task: dict, policy: dict, threads: int | None = None):
        self.task, self.policy, self.threads = task, policy, threads
        self.session = None
        self.using = {"key": None, "own": policy}
        self.mesh = self.parts = self.render_dir = None
        self.candidate, self.load_error, self.clock = -1, None, time.perf_counter()

    def setup(self) -> dict:
        """Build the task session; returns where this actor runs and ``status``: ``ready``, ``missing``
        (``module`` names what cannot be imported), ``unavailable`` (the policy's server) or ``fatal``."""
        import ray

        where = {"node_id": ray.get_runtime_context().get_node_id(), "ip": ray.util.get_node_ip_address(),
                 "host": socket.gethostname(), "pid": os.getpid(), "python": sys.version.split()[0],
                 "ray": ray.__version__}
        try:
            from grt.evaluators import pool
            from grt.evaluators.worker_env import accept_numpy2_pickles
        except BaseException as exc:
            return {**where, "status": "missing" if _missing_module(exc) else "fatal",
                    "module": _missing_module(exc), "error": traceback.format_exc()}
        accept_numpy2_pickles()  # a policy's own numpy 1.x (worker_path) reads the driver's geometry
        try:
            self.session = pool.build_session(self.task, self.policy)
        except BaseException as exc:
            if (down := pool._policy_down(exc)) is not None:
                return {**where, "status": "unavailable", "error": down}
            module = _missing_module(exc)
            return {**where, "status": "missing" if module else "fatal", "module": module,
                    "error": traceback.format_exc()}
        if self.threads and "torch" in sys.modules:
            sys.modules["torch"].set_num_threads(self.threads)
        gc.collect()
        gc.freeze()  # as a pool worker: ManiSkill's reconfigure runs gc.collect()
        return {**where, "status": "ready"}

    def load(self, geometry: tuple, policy: dict | None, seeds: list[int], render_dir: str | None,
             candidate: int) -> str | None:
        """Prepare a job: ``geometry`` is ``(vertices, faces, parts, metadata)`` (from the object store; vertices
        ``None``: the task's stock object). Returns ``None`` or why its trials cannot run (each then is a
        ``sim_error``)."""
        from grt.evaluators.base import candidate_mesh
        from grt.evaluators.pool import prepare_job

        vertices, faces, parts, metadata = geometry
        self.clock = time.perf_counter()  # the job's first trial's time includes this loading
        self.mesh = candidate_mesh(vertices, faces, metadata)
        self.parts, self.render_dir, self.candidate = parts, render_dir, int(candidate)
        self.load_error = prepare_job(self.session, self.mesh, parts, list(seeds), policy, self.using)
        return self.load_error

    def trial(self, seed: int) -> tuple:
        """One trial of the loaded job: ``("trial", seed, outcome, seconds)``, or ``("unavailable",
        message)`` when the policy's server stayed down."""
        from grt.evaluators.pool import run_seed
        from grt.policies.base import PolicyUnavailable

        try:
            outcome, self.load_error = run_seed(self.session, self.mesh, self.parts, int(seed), self.load_error,
                                                self.render_dir, self.candidate)
        except PolicyUnavailable as exc:
            return ("unavailable", str(exc))
        now = time.perf_counter()
        seconds, self.clock = now - self.clock, now
        return ("trial", int(seed), outcome, seconds)

    def pid(self) -> int:
        """This actor's process id (tests kill it)."""
        return os.getpid()

    def close(self) -> None:
        """Close the session (its simulator and policy connection) before the actor is killed."""
        if self.session is not None:
            self.session.close()
            self.session = None
