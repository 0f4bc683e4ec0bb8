"""``evaluator=ray``: the simulator workers as Ray actors, on this machine or across a cluster.

:class:`RayPool` has the interface of :class:`grt.evaluators.pool.WorkerPool` and its semantics, so
:class:`RayEvaluator` is :class:`grt.evaluators.sim.SimEvaluator` with another pool:

* each actor (:class:`grt.evaluators.ray_actor.SimActor`, ``num_cpus`` / ``num_gpus`` / custom
  ``resources`` each) builds one task session once and runs (candidate, seeds) jobs; a job's candidate
  geometry is put in Ray's object store once per candidate and evaluation;
* the driver sends a job's trials one call each, two in flight per actor (no idle gap between trials),
  and counts a trial only when its result arrives: a dead actor or node is replaced and the seeds it had
  not finished run again; the seed that was running when it died is blamed, and one that kills actors
  more than ``max_retries`` times is a ``sim_error`` (an actor that dies can take the answer of its last
  finished trial with it: after a death with two trials unanswered, the job's trials go one at a time
  and only the next death blames a seed); a call silent past ``trial_timeout`` kills its actor;
* a trial's outcome depends only on (mesh, seed), and jobs are cut as the pool cuts them, so scores and
  per-trial outcomes equal the pool's bit for bit;
* only the driver writes the run folder; Ctrl-C stops the actors (and the Ray it started) and the journal
  keeps every candidate finished before.

``address``: ``local`` starts Ray on this machine with one CPU per worker (stopped again at the end);
``auto`` joins the cluster ``ray start`` made on this machine (or ``$RAY_ADDRESS``); ``HOST:PORT`` joins
a cluster's head; ``ray://HOST:PORT`` goes through Ray Client. Bad addresses, version mismatches and nodes
that cannot import GRT are one-line :class:`ClusterError` messages.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import socket
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass, field

from grt.errors import UserError
from grt.evaluators.base import Job, OnTrial, TrialPool
from grt.evaluators.pool import THREAD_VARIABLES, blame_first_seed, worker_limits
from grt.evaluators.sim import SimEvaluator
from grt.evaluators.worker_env import python_path, worker_path
from grt.policies.base import PolicyServerError
from grt.targets import worker_error

log = logging.getLogger(__name__)
#: trial calls in flight per actor: the next one waits in the actor while the current one runs
DEPTH = 2
START_CLUSTER = ("start one with `ray start --head --num-cpus N` (then `ray start --address HEAD:6379` on each "
                 "other node), or use evaluator.address=local")


class ClusterError(UserError):
    """A Ray cluster that cannot be used: unreachable, another Ray/Python version, a node without GRT."""


# ------------------------------------------------------------------------------------ connection
def _ray():
    import ray

    return ray


def _check_reachable(address: str) -> None:
    """Refuse a ``HOST:PORT`` or ``ray://HOST:PORT`` nobody listens on, at once (Ray would retry for long)."""
    hostport = address.split("://", 1)[1] if "://" in address else address
    host, sep, port = hostport.rpartition(":")
    if not sep or not port.isdigit():
        raise ClusterError(f"evaluator.address={address}: not an address; give local, auto, HOST:PORT (a cluster's "
                           "head, e.g. 10.0.0.1:6379) or ray://HOST:10001 (Ray Client)")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=3.0):
            pass
    except OSError as exc:
        raise ClusterError(f"evaluator.address={address}: no Ray cluster answers there ({exc.strerror or exc}); "
                           f"{START_CLUSTER}") from None


_VERSIONS = re.compile(r"Ray:\s*(\S+)\s+Python:\s*(\S+)")


def version_mismatch(message: str, address: str) -> str | None:
    """The one line for Ray's version-mismatch error ``message`` (driver and cluster differ), or ``None``."""
    if "version mismatch" not in message.lower() and "versions differ" not in message.lower() \
            and "Changing the ray version" not in message:
        return None
    found = _VERSIONS.findall(message)
    if len(found) >= 2:
        (c_ray, c_py), (d_ray, d_py) = found[0], found[1]
        return (f"evaluator.address={address}: the cluster runs Ray {c_ray} on Python {c_py}, this machine Ray {d_ray} "
                f"on Python {d_py}; install the same versions on both (pip install 'ray[default]=={c_ray}')")
    first = " ".join(message.split())[:300]
    return f"evaluator.address={address}: Ray or Python versions differ between this machine and the cluster ({first})"


def connect(address: str, cpus: float, gpus: float, object_store_mb: int | None) -> bool:
    """Connect this process to Ray (start it for ``local``); returns whether this call started it.

    Raises:
        ClusterError: nothing to join at ``address``, or the cluster runs another Ray or Python version.
    """
    ray = _ray()
    if ray.is_initialized():  # the user's own program already joined a cluster: use that one
        return False
    address = str(address)
    kwargs = {"logging_level": logging.WARNING, "log_to_driver": True, "include_dashboard": False}
    if address == "local":
        kwargs.update(address="local", num_cpus=cpus, num_gpus=gpus or None)
        if object_store_mb:
            kwargs["object_store_memory"] = int(object_store_mb) * 1024 * 1024
    else:
        if address != "auto":
            _check_reachable(address)
        kwargs = {"address": address, "logging_level": logging.WARNING, "log_to_driver": True}
    handler = signal.getsignal(signal.SIGTERM)  # ray.init installs its own; the CLI's must stay
    # Ray warns on every start that token authentication is on; for a Ray of our own on this machine that
    # says nothing (a cluster's own start prints it once, where its operator reads it)
    quiet = logging.getLogger("ray._private.authentication.authentication_token_setup")
    level = quiet.level
    if address == "local":
        quiet.setLevel(logging.ERROR)
    try:
        ray.init(**kwargs)
    except ConnectionError as exc:
        if _refused_token(exc):
            raise ClusterError(f"evaluator.address={address}: the cluster refused this machine's connection: it has "
                               "token authentication on, and Ray sends its token to a given address only when told "
                               "to; set RAY_AUTH_MODE=token here and give the cluster's token (the head's "
                               "~/.ray/auth_token, or RAY_AUTH_TOKEN)") from None
        raise ClusterError(f"evaluator.address={address}: no running Ray cluster found ({' '.join(str(exc).split())[:200]}); "
                           f"{START_CLUSTER}") from None
    except Exception as exc:
        line = version_mismatch(str(exc), address)
        if line is not None:
            raise ClusterError(line) from None
        if address == "local":
            raise
        raise ClusterError(f"evaluator.address={address}: could not join the Ray cluster: "
                           f"{type(exc).__name__}: {' '.join(str(exc).split())[:300]}") from None
    finally:
        quiet.setLevel(level)
        if threading.current_thread() is threading.main_thread() and handler is not None:
            signal.signal(signal.SIGTERM, handler)
    return True


def _refused_token(exc: BaseException) -> bool:
    """Whether a failed ``ray.init`` was refused for a missing or wrong authentication token."""
    for _ in range(10):
        if exc is None:
            return False
        if type(exc).__name__ == "AuthenticationError" or "InvalidAuthToken" in str(exc):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def actor_class():
    """:class:`~grt.evaluators.ray_actor.SimActor` as a Ray actor class, its module sent by value."""
    ray = _ray()
    from grt.evaluators import ray_actor

    ray.cloudpickle.register_pickle_by_value(ray_actor)
    return ray.remote(ray_actor.SimActor)


def node_label(node: dict) -> str:
    """``IP/node-id prefix``: two nodes on one machine share the IP."""
    return f"{node['ip']}/{node['node_id'][:8]}"


# ------------------------------------------------------------------------------------ the pool
@dataclass
class _Actor:
    handle: object
    setup: object | None  # the setup call's reference until it answered
    started: float = field(default_factory=time.monotonic)
    node: dict | None = None
    job: Job | None = None
    inflight: deque = field(default_factory=deque)  # (reference, "load" | seed), in the order sent
    queued: int = 0  # seeds of job.seeds sent (the first ones)
    since: float = field(default_factory=time.monotonic)  # when the oldest call in flight became the oldest

    @property
    def ready(self) -> bool:
        return self.setup is None and self.node is not None


class RayPool(TrialPool):
    """Simulator actors on a Ray cluster (``evaluator=ray``'s :class:`~grt.evaluators.base.TrialPool`), with
    :class:`~grt.evaluators.pool.WorkerPool`'s semantics.

    Args:
        task, policy: plain-dict configs.
        workers: actors to start (fewer where the cluster has fewer CPUs: a warning names both numbers).
        max_retries, trial_timeout, startup_timeout, threads: as the pool's.
        address: ``local``, ``auto``, ``HOST:PORT`` or ``ray://HOST:PORT`` (module docstring).
        num_cpus, num_gpus, resources: each actor's Ray resources.
        runtime_env: Ray runtime environment of the actors (``working_dir``, ``pip``, ``env_vars``, ...).
        object_store_mb: object store size of a ``local`` Ray (``None``: Ray's default, 30% of memory).
    """

    def __init__(self, task: dict, policy: dict, workers: int = 2, max_retries: int = 2,
                 trial_timeout: float | None = 600.0, startup_timeout: float = 300.0, threads: int | None = 1,
                 address: str = "local", num_cpus: float = 1, num_gpus: float = 0, resources: dict | None = None,
                 runtime_env: dict | None = None, object_store_mb: int | None = 512):
        if workers < 1:
            raise ClusterError(f"budget.workers={workers}: give at least 1 actor")
        if num_cpus < 0 or (num_gpus or 0) < 0:
            raise ClusterError(f"evaluator.num_cpus={num_cpus}, evaluator.num_gpus={num_gpus}: resources cannot be "
                               "negative")
        if num_cpus == 0 and not num_gpus and not resources:
            raise ClusterError("evaluator.num_cpus=0 with no num_gpus or resources would start unbounded actors; "
                               "give each actor num_cpus=1 (one simulator uses one core)")
        for key, value in (("runtime_env", runtime_env), ("resources", resources)):
            if value is not None and not isinstance(value, Mapping):
                raise ClusterError(f"evaluator.{key}={value!r}: give a mapping ("
                                   + ("Ray's runtime environment: evaluator.runtime_env={working_dir: ., env_vars: "
                                      "{NAME: VALUE}}" if key == "runtime_env" else "evaluator.resources={NAME: AMOUNT}")
                                   + "), or null")
        if runtime_env is not None and not isinstance(runtime_env.get("env_vars") or {}, Mapping):
            raise ClusterError(f"evaluator.runtime_env.env_vars={runtime_env['env_vars']!r}: give a mapping "
                               "{NAME: VALUE}")
        self.task, self.policy = task, policy
        self.address, self.max_retries = str(address), int(max_retries)
        self.trial_timeout, self.startup_timeout = trial_timeout, startup_timeout
        self.num_cpus, self.num_gpus, self.resources = float(num_cpus), float(num_gpus or 0), dict(resources or {})
        self.threads = int(threads) if threads else None
        self.runtime_env = dict(runtime_env or {})
        if self.threads:
            env = {k: str(self.threads) for k in THREAD_VARIABLES}
            self.runtime_env["env_vars"] = {**env, **dict(self.runtime_env.get("env_vars") or {})}
        if self.address == "local":  # this machine: the driver's sys.path, as the pool's spawned workers have it
            env = self.runtime_env.setdefault("env_vars", {})
            env.setdefault("PYTHONPATH", os.pathsep.join(p for p in sys.path if p and os.path.isdir(p)))
        if folders := worker_path(policy):  # the policy's own libraries first (grt/evaluators/worker_env.py)
            env = self.runtime_env["env_vars"] = dict(self.runtime_env.get("env_vars") or {})
            env["PYTHONPATH"] = python_path(folders, env.get("PYTHONPATH"))
        if self.address == "local":  # ... and bounded by its cores and memory, as the pool is
            self.limits = worker_limits(workers)
            if self.limits["used"] < workers:
                log.warning("workers=%d: starting %d Ray actors, as many as this machine holds (%d CPU cores, "
                            "~%d MB per worker)", workers, self.limits["used"], self.limits["cores"],
                            self.limits["worker_mb"])
        else:
            self.limits = {"requested": int(workers), "used": int(workers)}
        self.num_workers = self.limits["used"]
        self.owned = connect(self.address, self.num_workers * max(self.num_cpus, 1.0),
                             self.num_workers * self.num_gpus, object_store_mb)
        self._fit_to_cluster()
        self.actors: list[_Actor] = []
        self.restarts = self.startup_failures = 0
        self.trials_per_node: Counter = Counter()
        self.nodes_seen: dict[str, dict] = {}
        self._careful: set[int] = set()  # jobs whose seeds go one call at a time (see _replace)
        self._cls = None

    # ---------------------------------------------------------------------------- cluster
    def _fit_to_cluster(self) -> None:
        """Fewer actors where the cluster lacks the CPUs (or GPUs) asked for: a warning with both numbers."""
        total = _ray().cluster_resources()
        fits = [self.num_workers]
        for name, each in (("CPU", self.num_cpus), ("GPU", self.num_gpus), *self.resources.items()):
            if each > 0:
                fits.append(int(total.get(name, 0.0) // each))
                if fits[-1] < self.num_workers:
                    log.warning("evaluator.address=%s: the cluster has %g %s, %d workers x %g = %g asked; starting %d "
                                "actors", self.address, total.get(name, 0.0), name, self.num_workers, each,
                                self.num_workers * each, max(fits[-1], 1))
        used = min(fits)
        if used < 1:
            self.close()
            raise ClusterError(f"evaluator.address={self.address}: the cluster has {total.get('CPU', 0):g} CPUs and "
                               f"{total.get('GPU', 0):g} GPUs, not enough for one actor (num_cpus={self.num_cpus:g}, "
                               f"num_gpus={self.num_gpus:g}, resources={self.resources}); add nodes or ask for less")
        self.limits.update(used=used, cluster=dict(sorted((k, v) for k, v in total.items()
                                                          if not k.startswith("node:") and "memory" not in k)))
        self.num_workers = used

    def info(self) -> dict:
        """The ``evaluator`` block of ``summary.json``: backend, address, nodes, trials per node."""
        ray = _ray()
        alive = [n for n in ray.nodes() if n.get("Alive")] if ray.is_initialized() else []
        return {"backend": "ray", "address": self.address, "ray": ray.__version__,
                "gcs_address": _gcs_address(), "nodes": len(alive),
                "nodes_used": len(self.nodes_seen), "actors": self.num_workers,
                "num_cpus": self.num_cpus, "num_gpus": self.num_gpus, "resources": self.resources,
                "trials_per_node": dict(sorted(self.trials_per_node.items())),
                "actors_replaced": self.restarts}

    # ---------------------------------------------------------------------------- actors
    def _spawn(self) -> _Actor:
        if self._cls is None:
            self._cls = actor_class()
        options = {"num_cpus": self.num_cpus, "max_restarts": 0, "max_concurrency": 1}
        if self.num_gpus:
            options["num_gpus"] = self.num_gpus
        if self.resources:
            options["resources"] = self.resources
        if self.runtime_env:
            options["runtime_env"] = self.runtime_env
        handle = self._cls.options(**options).remote(self.task, self.policy, self.threads)
        return _Actor(handle, handle.setup.remote())

    def start(self) -> None:
        """Start the missing actors (each builds its session in parallel with the others)."""
        while len(self.actors) < self.num_workers:
            self.actors.append(self._spawn())

    @property
    def all_ready(self) -> bool:
        return len(self.actors) == self.num_workers and all(a.ready for a in self.actors)

    def wait_ready(self) -> None:
        """Start the actors and return once every one has built its session."""
        self.start()
        while not all(a.ready for a in self.actors):
            self._poll(lambda *_: None, deque(), {})

    def run(self, jobs: deque[Job] | list[Job], on_trial: OnTrial) -> None:
        """Run every job's seeds; ``on_trial(job, outcome, seconds)`` once per seed, in any order; ``on_trial``
        may add jobs to a ``deque`` given as ``jobs`` (the pool's)."""
        self.start()
        self._geometry: dict[int, object] = {}
        self._careful = set()
        pending, crashes = jobs if isinstance(jobs, deque) else deque(jobs), {}
        try:
            while pending or any(a.job is not None for a in self.actors):
                self._assign(pending)
                self._poll(on_trial, pending, crashes)
        finally:
            self._geometry = {}  # frees the candidates in the object store

    def _assign(self, pending: deque) -> None:
        ray = _ray()
        for a in self.actors:
            if a.ready and a.job is None and pending:
                job = a.job = pending.popleft()
                if job.candidate not in self._geometry:
                    self._geometry[job.candidate] = ray.put((job.vertices, job.faces, job.parts, job.metadata))
                ref = a.handle.load.remote(self._geometry[job.candidate], job.policy, list(job.seeds),
                                           job.render_dir, job.candidate)
                a.inflight.append((ref, "load"))
                a.queued, a.since = 0, time.monotonic()
            if a.job is not None:
                depth = 1 if a.job.job_id in self._careful else DEPTH
                while a.queued < min(depth, len(a.job.seeds)):
                    seed = a.job.seeds[a.queued]
                    a.inflight.append((a.handle.trial.remote(seed), seed))
                    a.queued += 1

    def _poll(self, on_trial, pending: deque, crashes: dict) -> None:
        """Wait up to a second for answers and handle them; replace dead actors, kill silent ones."""
        ray = _ray()
        refs = [a.setup for a in self.actors if a.setup is not None]
        refs += [ref for a in self.actors for ref, _ in a.inflight]
        if refs:
            ray.wait(refs, num_returns=1, timeout=1.0)
            done = set(ray.wait(refs, num_returns=len(refs), timeout=0)[0])
        else:
            time.sleep(0.05)
            done = set()
        for a in list(self.actors):
            try:
                if a.setup is not None:
                    if a.setup in done:
                        self._started(a, ray.get(a.setup))
                    elif self._late(a, self.startup_timeout, a.started):
                        self._kill(a)
                        self._replace(a, on_trial, pending, crashes, f"did not start in {self.startup_timeout:g} s")
                    continue
                while a.inflight and a.inflight[0][0] in done:
                    ref, what = a.inflight[0]
                    answer = ray.get(ref)  # raises when the actor died: the call stays unanswered
                    a.inflight.popleft()
                    self._answer(a, what, answer, on_trial)
                    a.since = time.monotonic()
                loading = a.inflight and a.inflight[0][1] == "load" and a.job is not None  # may plan every trial
                limit = self.trial_timeout * max(1, len(a.job.seeds)) if loading and self.trial_timeout else \
                    self.trial_timeout
                if a.inflight and self._late(a, limit, a.since):
                    log.warning("Ray actor on %s silent for too long: killing it", node_label(a.node))
                    self._kill(a)
                    self._replace(a, on_trial, pending, crashes, "timed out (hung)")
            except ray.exceptions.RayError as exc:  # the actor (or its node) died
                why = "died" if isinstance(exc, ray.exceptions.RayActorError) else f"failed ({type(exc).__name__})"
                where = f" on {node_label(a.node)}" if a.node else ""
                self._kill(a)
                self._replace(a, on_trial, pending, crashes, f"{why}{where}",
                              died=isinstance(exc, ray.exceptions.RayActorError))

    @staticmethod
    def _late(a: _Actor, limit: float | None, since: float) -> bool:
        return limit is not None and time.monotonic() - since > limit

    def _started(self, a: _Actor, report: dict) -> None:
        a.setup = None
        status = report.get("status")
        where = f"{report.get('host')} ({report.get('ip')})"
        if status == "ready":
            a.node = report
            self.nodes_seen[node_label(report)] = report
            return
        self.close()
        if status == "missing":
            raise ClusterError(f"evaluator=ray: the node {where} cannot import {report.get('module')!r} (Python "
                               f"{report.get('python')}); install GRT and the task's modules there in the same "
                               "environment (pip install -e . on a shared disk), or ship them with "
                               "evaluator.runtime_env.py_modules")
        if status == "unavailable":
            raise PolicyServerError(f"{report.get('error')}; the evaluation stopped (nothing of its unfinished trials "
                                    "was recorded)")
        raise worker_error("task.session", str(self.task["session"].get("_target_")), str(report.get("error")),
                           f"an evaluator actor on {where}")

    def _answer(self, a: _Actor, what, answer, on_trial) -> None:
        if what == "load":
            return  # a load error comes back with each trial, as a sim_error
        if answer[0] == "unavailable":
            self.close()
            raise PolicyServerError(f"{answer[1]}; the evaluation stopped (nothing of its unfinished trials was "
                                    "recorded)")
        _, seed, outcome, seconds = answer
        job = a.job
        job.seeds.remove(seed)
        a.queued -= 1
        self.trials_per_node[node_label(a.node)] += 1
        on_trial(job, outcome, seconds)
        if not job.seeds:
            a.job = None

    def _kill(self, a: _Actor) -> None:
        with contextlib.suppress(Exception):
            _ray().kill(a.handle, no_restart=True)

    def _replace(self, a: _Actor, on_trial, pending: deque, crashes: dict, why: str, died: bool = False) -> None:
        """Start a new actor in ``a``'s place; blame the seed it was running, re-queue the rest of its job.

        An actor sends a call's answer after the call returned, so one that died (``died``) may have taken
        the answer of the trial before the fatal one with it: with two trials unanswered, which one killed it
        is unknown. Then no seed is blamed, and the job's seeds go one call at a time from then on (no answer
        can be lost: the next call is sent once the last answer came), so a next death names its seed.
        """
        job, self.restarts = a.job, self.restarts + 1
        if job is None and not a.ready:
            self.startup_failures += 1
            if self.startup_failures > self.num_workers * (self.max_retries + 1):
                self.close()
                raise RuntimeError(f"evaluator actors keep dying while starting: last one {why}")
            log.warning("Ray actor %s while starting; starting another", why)
        elif job is not None and job.seeds and died and job.job_id not in self._careful \
                and sum(what != "load" for _, what in a.inflight) > 1:
            self._careful.add(job.job_id)
            log.warning("Ray actor %s on candidate %d, seed %s or %s; starting another (the job's trials now one "
                        "at a time)", why, job.candidate, *[w for _, w in a.inflight if w != "load"][:2])
            pending.appendleft(job)
        elif job is not None and job.seeds:
            blame_first_seed(job, crashes, self.max_retries, on_trial, pending, f"Ray actor {why}",
                             "starting another", f"Ray actor {why}")
        self.actors[self.actors.index(a)] = self._spawn()

    def close(self) -> None:
        """Stop every actor (each closes its session first), and the Ray this pool started."""
        ray = _ray()
        if not ray.is_initialized():
            self.actors = []
            return
        closing = [a.handle.close.remote() for a in getattr(self, "actors", []) if a.ready]
        with contextlib.suppress(Exception):
            ray.wait(closing, num_returns=len(closing), timeout=10.0)
        for a in getattr(self, "actors", []):
            self._kill(a)
        self.actors = []
        if self.owned:
            ray.shutdown()
            self.owned = False


def _gcs_address() -> str | None:
    with contextlib.suppress(Exception):
        return _ray().get_runtime_context().gcs_address
    return None


# ------------------------------------------------------------------------------------ evaluator
class RayEvaluator(SimEvaluator):
    """:class:`~grt.evaluators.sim.SimEvaluator` whose workers are Ray actors (:class:`RayPool`).

    Args (besides the simulator evaluator's):
        address: ``local`` (default: Ray started on this machine with ``workers`` CPUs), ``auto``,
            ``HOST:PORT`` or ``ray://HOST:PORT``.
        num_cpus, num_gpus, resources: Ray resources per actor.
        runtime_env: the actors' Ray runtime environment.
        object_store_mb: object store of a ``local`` Ray.
        startup_timeout: seconds an actor may take to be placed and build its session.
    """

    def __init__(self, task: dict, policy: dict, workers: int = 2, address: str = "local", num_cpus: float = 1,
                 num_gpus: float = 0, resources: dict | None = None, runtime_env: dict | None = None,
                 object_store_mb: int | None = 512, startup_timeout: float = 300.0, **kwargs):
        self._ray_options = {"address": address, "num_cpus": num_cpus, "num_gpus": num_gpus,
                             "resources": resources, "runtime_env": runtime_env,
                             "object_store_mb": object_store_mb}
        self._startup_timeout = startup_timeout
        super().__init__(task, policy, workers=workers, **kwargs)

    def _make_pool(self) -> TrialPool:
        a = self._pool_args
        return RayPool(self.task, self.policy, a["workers"], a["max_retries"], self.trial_timeout,
                       self._startup_timeout, a["threads"], **self._ray_options)

    def start(self, say=lambda line: print(line, flush=True)) -> float:
        if say is not None and not self.pool.all_ready:
            ray = _ray()
            nodes = sum(1 for n in ray.nodes() if n.get("Alive"))
            say(f"Ray {ray.__version__} at {self.pool.address} ({_gcs_address()}): {nodes} node{'s' * (nodes != 1)}, "
                f"{self.pool.limits['cluster'].get('CPU', 0):g} CPUs")
        return super().start(say)

