"""GpuEvaluator (``evaluator=gpu``): a whole population in the parallel sub-scenes of one GPU simulation.

Per :meth:`GpuEvaluator.evaluate` call, every (candidate, seed) pair becomes one sub-scene of a ManiSkill env
on ``physx_cuda``: sub-scene ``i`` holds candidate ``c(i)`` and runs the episode of seed ``s(i)`` (the same
seeded start as the CPU trial with that seed, :mod:`grt.tasks.batched`). The pairs are laid out candidate
by candidate (:func:`plan_batches`); a population larger than ``max_envs`` is split into equal batches (the
last padded with repeats of its last pair, whose outcomes are dropped), so one env size serves them all.
Per batch the scene is rebuilt once (a reconfigure: the robot, the table and every sub-scene's object)
and the episodes run together, the policy acting on ``(N, obs)`` batches on the GPU; never a reconfigure
per trial. The env is rebuilt from scratch every ``recreate_every`` batches (GPU memory grows over repeated
reconfigures: ManiSkill issues 466, 965) and when the batch size changes.

:class:`GpuPool` is a :class:`grt.evaluators.base.TrialPool`: the evaluator is the CPU evaluators' (seeds,
collision parts, racing in rounds, results), so the journal's format does not depend on where the trials ran.
With ``budget.racing`` each round of the candidates still running is one set of batches. A candidate's
``wall_s`` is its share of its batches' seconds.
The GPU's physics is not the CPU's (PhysX GPU solver, hulls capped at 64 vertices on both, pytorch-kinematics
IK in the arm's controller): outcomes agree in distribution, not trial for trial.

The same code runs on ``physx_cpu`` with one sub-scene per env (``backend=physx_cpu``, ``max_envs=1``): the
CI tests its whole path there, and its outcomes equal the CPU worker pool's trial for trial.
"""

from __future__ import annotations

import inspect
import math
import time
from collections import deque
from dataclasses import dataclass

import trimesh

from grt.errors import UserError
from grt.evaluators.base import Job, OnTrial, PoolEvaluator, TrialPool, sim_error
from grt.evaluators.collision import MAX_HULL_VERTICES
from grt.targets import instantiate, locate

BACKENDS = ("physx_cuda", "physx_cpu")


class GpuEvaluatorError(UserError):
    """``evaluator=gpu`` asked for what it cannot run (no CUDA, a task or policy that cannot run batched)."""


@dataclass(frozen=True)
class Batch:
    """The sub-scenes of one env: sub-scene ``i`` holds the object of job ``jobs[i]`` on seed ``seeds[i]``.

    Attributes:
        jobs, seeds: one entry per sub-scene (``jobs``: indices into the jobs being laid out).
        real: the first ``real`` sub-scenes are the population's pairs; the rest repeat the last one to
            keep every batch the same size (their outcomes are dropped).
    """

    jobs: tuple[int, ...]
    seeds: tuple[int, ...]
    real: int

    def __len__(self) -> int:
        return len(self.seeds)


def plan_batches(pairs: list[tuple[int, int]], max_envs: int) -> list[Batch]:
    """Lay (job, seed) pairs out on sub-scenes, in order, in as few equal batches of at most ``max_envs``
    sub-scenes as hold them all.

    Args:
        pairs: ``(job, seed)``: the job's object runs the episode of that seed (jobs: the caller's indices).
        max_envs: the most sub-scenes one env may have.

    Returns:
        The batches; every pair is in exactly one batch's first ``real`` sub-scenes.
    """
    if max_envs < 1:
        raise ValueError(f"max_envs must be >= 1, got {max_envs}")
    if not pairs:
        return []
    size = math.ceil(len(pairs) / math.ceil(len(pairs) / max_envs))
    batches = []
    for lo in range(0, len(pairs), size):
        chunk = list(pairs[lo:lo + size])
        real = len(chunk)
        chunk += [chunk[-1]] * (size - real)
        batches.append(Batch(tuple(j for j, _ in chunk), tuple(s for _, s in chunk), real))
    return batches


def objects_of(batch: Batch) -> tuple[list[int], list[int]]:
    """``(distinct jobs in order of first use, per sub-scene index into them)``: each job's object loads once."""
    order: dict[int, int] = {}
    for j in batch.jobs:
        order.setdefault(j, len(order))
    return list(order), [order[j] for j in batch.jobs]


def check_batched(task: dict, policy: dict | None = None, backend: str = "physx_cuda", max_envs: int = 1) -> None:
    """Refuse, before anything runs, a task or policy that cannot run in parallel sub-scenes, or more
    sub-scenes per env than the backend allows.

    Raises:
        GpuEvaluatorError: one line naming what cannot run batched and what to use instead.
    """
    from grt.policies.base import policy_kind
    from grt.tasks import session_class
    from grt.tasks.batched import EpisodeSession

    cls = session_class(task)
    if not issubclass(cls, EpisodeSession):
        raise GpuEvaluatorError(f"evaluator=gpu runs tasks whose episodes run batched in parallel sub-scenes "
                                f"(insertion, drawer, ManiSkill tasks); task={task.get('name', '?')} ({cls.__name__}) does not: use "
                                "evaluator=sim (CPU workers)")
    limit = cls.max_sub_scenes(backend)
    if limit is not None and int(max_envs) > limit:
        raise GpuEvaluatorError(f"evaluator.backend={backend} runs {limit} sub-scene{'s' * (limit != 1)} per env, "
                                f"evaluator.max_envs={max_envs}: set evaluator.max_envs={limit}")
    target = (policy or {}).get("_target_")
    obj = locate(str(target), "policy") if target else None
    if isinstance(obj, type) and policy_kind(obj) != "closed_loop":
        raise GpuEvaluatorError(f"evaluator=gpu steps every sub-scene with one batched policy (observations (N, ...) "
                                f"in, actions out); {obj.__name__} is per-env ({policy_kind(obj) or 'no act method'}, "
                                "e.g. a motion planner): use evaluator=sim (CPU workers)")


def _accepts(target, name: str) -> bool:
    try:
        return name in inspect.signature(target).parameters
    except (TypeError, ValueError):
        return False


class GpuPool(TrialPool):
    """The parallel sub-scenes of one ManiSkill env (``evaluator=gpu``'s :class:`~grt.evaluators.base.TrialPool`).

    :meth:`run` takes every job queued, lays its (candidate, seed) pairs out on sub-scenes
    (:func:`plan_batches`), rebuilds the env around each batch's objects and runs its episodes at once; the jobs
    ``on_trial`` queued meanwhile (racing: the next round of the candidates that go on) form the next batches.
    A candidate the task would not load (:meth:`~grt.tasks.base.TaskSession.check_candidate`) takes no sub-scene:
    its trials end in ``sim_error`` as a CPU worker records them. Arguments: :class:`GpuEvaluator`'s.
    """

    def __init__(self, task: dict, policy: dict, backend: str, max_envs: int, recreate_every: int,
                 render_backend: str, sim_config: dict | None, device: str | None):
        from grt.tasks import session_class

        check_batched(task, policy, backend, max_envs)
        if backend == "physx_cuda":
            _require_cuda()
        self.task, self.backend, self.max_envs = task, backend, int(max_envs)
        self.device = device or ("cuda" if backend == "physx_cuda" else "cpu")
        self.session_class = session_class(task)
        self.recreate_every, self.render_backend = int(recreate_every), str(render_backend)
        self.sim_config = dict(sim_config or {})
        self.policy = self._build_policy(policy)
        self._policies: dict[str | None, object] = {None: self.policy}  # a job's policy config -> built
        self.session, self._uses = None, 0
        self.stats = {"batches": 0, "sub_scenes": 0, "envs_built": 0, "build_s": 0.0, "episodes_s": 0.0,
                      "gpu_free_mb": [], "hulls": 0, "max_hull_inflation_mm": 0.0}

    def job_size(self, seeds: int) -> int:
        """All of a candidate's seeds in one job: the pool lays every pair out on sub-scenes itself."""
        return max(1, seeds)

    def run(self, jobs: deque[Job], on_trial: OnTrial) -> None:
        refused: dict[int, str | None] = {}
        while jobs:
            taken = list(jobs)
            jobs.clear()
            groups: dict[str | None, list[Job]] = {}
            for job in taken:
                reason = self._refusal(job, refused)
                if reason is not None:
                    for seed in job.seeds:
                        on_trial(job, sim_error(seed, reason), 0.0)
                else:
                    groups.setdefault(None if job.policy is None else repr(sorted(job.policy.items())), []).append(job)
            for key, group in groups.items():
                self._run_jobs(group, self._acting(key, group[0].policy), on_trial)

    def _run_jobs(self, group: list[Job], policy, on_trial: OnTrial) -> None:
        """Every (job, seed) pair of ``group`` in batches of sub-scenes, each trial called back as its batch ends."""
        pairs = [(k, seed) for k, job in enumerate(group) for seed in job.seeds]
        for batch in plan_batches(pairs, self.max_envs):
            outcomes, seconds = self._run_batch(batch, group, policy)
            for k in range(batch.real):
                on_trial(group[batch.jobs[k]], outcomes[k], seconds / len(batch))

    def _run_batch(self, batch: Batch, group: list[Job], policy) -> tuple[list, float]:
        """One batch: (re)build the env around its objects, run every sub-scene's episode."""
        begin = time.perf_counter()
        session = self._session(len(batch))
        if session.policy is not policy:
            session.set_policy(policy)
        order, assignment = objects_of(batch)
        session.load_objects([(group[j].mesh(), group[j].parts) for j in order], assignment)
        built = time.perf_counter()
        outcomes = session.run_episodes(list(batch.seeds))
        done = time.perf_counter()
        self.stats["batches"] += 1
        self.stats["sub_scenes"] += len(batch)
        self.stats["build_s"] += built - begin
        self.stats["episodes_s"] += done - built
        tally = session.hull_tally()  # how much PhysX grew the hulls (on the GPU: 64 vertices, 64 polygons)
        self.stats["hulls"] += int(tally.get("parts", 0))
        self.stats["max_hull_inflation_mm"] = max(self.stats["max_hull_inflation_mm"],
                                                  1000.0 * float(tally.get("max_inflation_m", 0.0)))
        if self.backend == "physx_cuda":
            import torch

            self.stats["gpu_free_mb"].append(round(torch.cuda.mem_get_info()[0] / 2**20))
        return outcomes, done - begin

    def _session(self, num_envs: int):
        """The env for ``num_envs`` sub-scenes: the current one, or a new one (other size, or ``recreate_every``)."""
        self._uses += 1
        if self.session is not None and self.session.num_envs == num_envs and self._uses <= self.recreate_every:
            return self.session
        self.close()
        self._uses = 1
        self.session = instantiate(self.task["session"], policy=self.policy, num_envs=num_envs,
                                   sim_backend=self.backend, render_backend=self.render_backend,
                                   sim_config=self.sim_config, _convert_="all")
        self.stats["envs_built"] += 1
        return self.session

    def _acting(self, key: str | None, config: dict | None):
        """The policy a job's config names (built once per config), or the pool's own."""
        if key not in self._policies:
            self._policies[key] = self._build_policy(config)
        return self._policies[key]

    def _build_policy(self, policy: dict):
        target = locate(str(policy["_target_"]), "policy")
        extra = {"device": self.device} if "device" not in policy and _accepts(target, "device") else {}
        return instantiate(policy, **extra)

    def _refusal(self, job: Job, seen: dict[int, str | None]) -> str | None:
        """Why the task would not load the job's candidate (:meth:`~grt.tasks.base.TaskSession.check_candidate`,
        once per candidate), as a CPU worker words it, or ``None``."""
        if job.candidate not in seen:
            seen[job.candidate] = None
            if job.vertices is not None:
                kwargs = {k: v for k, v in self.task["session"].items() if k != "_target_"}
                try:
                    self.session_class.check_candidate(job.mesh(), **kwargs)
                except Exception as exc:  # noqa: BLE001 - whatever the task refuses
                    seen[job.candidate] = f"load_object failed: {type(exc).__name__}: {exc}"
        return seen[job.candidate]

    def info(self) -> dict:
        device = None
        if self.backend == "physx_cuda":
            import torch

            device = torch.cuda.get_device_name(0)
        return {"backend": "gpu", "sim_backend": self.backend, "device": device, "max_envs": self.max_envs,
                "recreate_every": self.recreate_every, **{k: (round(v, 3) if isinstance(v, float) else v)
                                                          for k, v in self.stats.items()}}

    def close(self) -> None:
        if self.session is not None:
            self.session.close()
            self.session = None


class GpuEvaluator(PoolEvaluator):
    """Score candidate meshes in the parallel sub-scenes of one GPU simulation (see the module docstring).

    Args (besides :class:`~grt.evaluators.base.PoolEvaluator`'s; ``policy``: a closed-loop, batched policy,
    built once, on ``device`` when its class takes a ``device`` argument; ``max_hull_vertices`` 64: PhysX's GPU
    limit per hull):
        backend: ``physx_cuda``, or ``physx_cpu`` (with ``max_envs=1``: the CPU test of this path).
        max_envs: the most sub-scenes of one env; a larger population is split into batches.
        recreate_every: rebuild the env from scratch after this many batches (GPU memory grows over
            reconfigures).
        render_backend: ManiSkill's (``none``: no renderer, no Vulkan needed).
        sim_config: ManiSkill's ``sim_config`` (e.g. ``gpu_memory_config``: contact buffer sizes).
        device: the policy's torch device (``None``: ``cuda`` on physx_cuda, else ``cpu``).
        render_dir: not supported (pictures per trial need evaluator=sim); must be ``None``.
    """

    result_info = {"evaluator": "gpu"}

    def __init__(self, task: dict, policy: dict, nominal: trimesh.Trimesh | None = None, collision: str = "fast",
                 coacd: dict | None = None, cache_dir: str | None = None,
                 max_hull_vertices: int = MAX_HULL_VERTICES, backend: str = "physx_cuda", max_envs: int = 2048,
                 recreate_every: int = 8, render_backend: str = "none", sim_config: dict | None = None,
                 device: str | None = None, progress: bool = True, render_dir: str | None = None):
        if backend not in BACKENDS:
            raise GpuEvaluatorError(f"evaluator.backend={backend} is not one of {', '.join(BACKENDS)}")
        if int(max_envs) < 1 or int(recreate_every) < 1:
            raise GpuEvaluatorError(f"evaluator.max_envs and evaluator.recreate_every must be >= 1, got {max_envs} "
                                    f"and {recreate_every}")
        if render_dir:
            raise GpuEvaluatorError("render=true writes a picture per trial, which evaluator=gpu does not: "
                                    "use evaluator=sim to render")
        self._pool_args = (backend, int(max_envs), int(recreate_every), render_backend, sim_config, device)
        super().__init__(task, policy, nominal, collision, coacd, cache_dir, max_hull_vertices, None, progress)
        self.backend, self.max_envs = backend, int(max_envs)

    def _make_pool(self) -> TrialPool:
        return GpuPool(self.task, self.policy, *self._pool_args)

    @classmethod
    def preflight(cls, task: dict, policy: dict, backend: str = "physx_cuda", max_envs: int = 2048, **_) -> None:
        """Refuse, before a run writes anything, what this evaluator cannot run (see :func:`check_batched`)."""
        check_batched(task, policy, backend, max_envs)
        if backend == "physx_cuda":
            _require_cuda()

    def start(self, say=lambda line: print(line, flush=True)) -> float:
        """Nothing to start ahead: the env is built for the first population's size; says so once."""
        if say is not None and self.pool.session is None:
            say(f"evaluator=gpu: {self.backend}, up to {self.max_envs} sub-scene{'s' * (self.max_envs != 1)} per env; "
                "the simulator is built for each population (a few seconds per rebuild)")
        return 0.0


def _require_cuda() -> None:
    import torch

    if not torch.cuda.is_available():
        raise GpuEvaluatorError("evaluator=gpu simulates on a CUDA GPU (physx_cuda), and torch sees none here: use "
                                "evaluator=sim (CPU workers), or evaluator.backend=physx_cpu evaluator.max_envs=1 to run "
                                "this evaluator's path one sub-scene at a time")
