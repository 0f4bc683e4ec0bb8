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

Results are :class:`grt.evaluators.base.CandidateResult`s, as the CPU evaluators give: the journal's format
does not depend on where the trials ran. A candidate's ``wall_s`` is its share of its batches' seconds.
The GPU's physics is not the CPU's (PhysX GPU solver, hulls capped at 64 vertices on both, pytorch-kinematics
IK in the arm's controller): outcomes agree in distribution, not trial for trial.

The same code runs on ``physx_cpu`` with one sub-scene per env (``backend=physx_cpu``, ``max_envs=1``): the
CI tests its whole path there, and its outcomes equal the CPU worker pool's trial for trial.
"""

from __future__ import annotations

import inspect
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh

from grt.console import progress as progress_bar
from grt.errors import UserError
from grt.evaluators.base import CandidateResult, Evaluator
from grt.evaluators.collision import MAX_HULL_VERTICES, CollisionError, make_collision, mesh_label
from grt.evaluators.pool import sim_error
from grt.tasks.base import TrialOutcome

log = logging.getLogger(__name__)

BACKENDS = ("physx_cuda", "physx_cpu")


class GpuEvaluatorError(UserError):
    """``evaluator=gpu`` asked for what it cannot run (no CUDA, a task or policy that cannot run batched)."""


@dataclass(frozen=True)
class Batch:
    """The sub-scenes of one env: sub-scene ``i`` holds candidate ``candidates[i]`` on seed ``seeds[i]``.

    Attributes:
        candidates, seeds: one entry per sub-scene.
        real: the first ``real`` sub-scenes are the population's pairs; the rest repeat the last one to
            keep every batch the same size (their outcomes are dropped).
    """

    candidates: tuple[int, ...]
    seeds: tuple[int, ...]
    real: int

    def __len__(self) -> int:
        return len(self.seeds)


def plan_batches(candidates: list[int], seeds: list[int], max_envs: int) -> list[Batch]:
    """Lay (candidate, seed) pairs out on sub-scenes: candidate by candidate, seeds in order, in as few
    equal batches of at most ``max_envs`` sub-scenes as hold them all.

    Args:
        candidates: the candidates' indices (in the caller's list of meshes).
        seeds: the episode seeds every candidate runs.
        max_envs: the most sub-scenes one env may have.

    Returns:
        The batches; every pair is in exactly one batch's first ``real`` sub-scenes.
    """
    if max_envs < 1:
        raise ValueError(f"max_envs must be >= 1, got {max_envs}")
    pairs = [(c, s) for c in candidates for s in seeds]
    if not pairs:
        return []
    size = math.ceil(len(pairs) / math.ceil(len(pairs) / max_envs))
    batches = []
    for lo in range(0, len(pairs), size):
        chunk = pairs[lo:lo + size]
        real = len(chunk)
        chunk += [chunk[-1]] * (size - real)
        batches.append(Batch(tuple(c for c, _ in chunk), tuple(s for _, s in chunk), real))
    return batches


def objects_of(batch: Batch) -> tuple[list[int], list[int]]:
    """``(distinct candidates in order of first use, per sub-scene index into them)``."""
    order: dict[int, int] = {}
    for c in batch.candidates:
        order.setdefault(c, len(order))
    return list(order), [order[c] for c in batch.candidates]


def check_batched(task: dict, policy: dict | None = None, backend: str = "physx_cuda", max_envs: int = 1) -> None:
    """Refuse, before anything runs, a task or policy that cannot run in parallel sub-scenes, or more
    sub-scenes per env than the backend allows.

    Raises:
        GpuEvaluatorError: one line naming what cannot run batched and what to use instead.
    """
    from hydra.utils import get_object

    from grt.policies.base import policy_kind
    from grt.tasks import session_class
    from grt.tasks.batched import BatchedEpisodes

    cls = session_class(task)
    if not issubclass(cls, BatchedEpisodes):
        raise GpuEvaluatorError(f"evaluator=gpu runs tasks whose episodes run batched in parallel sub-scenes "
                                f"(insertion, drawer); task={task.get('name', '?')} ({cls.__name__}) does not: use "
                                "evaluator=sim (CPU workers)")
    limit = cls.max_sub_scenes(backend)
    if limit is not None and int(max_envs) > limit:
        raise GpuEvaluatorError(f"evaluator.backend={backend} runs {limit} sub-scene{'s' * (limit != 1)} per env, "
                                f"evaluator.max_envs={max_envs}: set evaluator.max_envs={limit}")
    target = (policy or {}).get("_target_")
    obj = get_object(str(target)) if target else None
    if isinstance(obj, type) and policy_kind(obj) != "closed_loop":
        raise GpuEvaluatorError(f"evaluator=gpu steps every sub-scene with one batched policy (observations (N, ...) "
                                f"in, actions out); {obj.__name__} is per-env ({policy_kind(obj) or 'no act method'}, "
                                "e.g. a motion planner): use evaluator=sim (CPU workers)")


def _accepts(target, name: str) -> bool:
    try:
        return name in inspect.signature(target).parameters
    except (TypeError, ValueError):
        return False


class GpuEvaluator(Evaluator):
    """Score candidate meshes in the parallel sub-scenes of one GPU simulation (see the module docstring).

    Args:
        task: task config as a plain dict; its ``session`` must be a :class:`grt.tasks.batched.BatchedEpisodes`.
        policy: policy config as a plain dict (a closed-loop, batched policy); built once, on ``device``
            when its class takes a ``device`` argument.
        nominal, collision, coacd, cache_dir, max_hull_vertices: the collision parts, as
            :class:`grt.evaluators.sim.SimEvaluator`'s (64 vertices: PhysX's GPU limit per hull).
        backend: ``physx_cuda``, or ``physx_cpu`` (with ``max_envs=1``: the CPU test of this path).
        max_envs: the most sub-scenes of one env; a larger population is split into batches.
        recreate_every: rebuild the env from scratch after this many batches (GPU memory grows over
            reconfigures).
        render_backend: ManiSkill's (``none``: no renderer, no Vulkan needed).
        sim_config: ManiSkill's ``sim_config`` (e.g. ``gpu_memory_config``: contact buffer sizes).
        device: the policy's torch device (``None``: ``cuda`` on physx_cuda, else ``cpu``).
        progress: show the trials' progress.
        render_dir: not supported (pictures per trial need evaluator=sim); must be ``None``.
    """

    def __init__(self, task: dict, policy: dict, nominal: trimesh.Trimesh | None = None, collision: str = "fast",
                 coacd: dict | None = None, cache_dir: str | None = None,
                 max_hull_vertices: int = MAX_HULL_VERTICES, backend: str = "physx_cuda", max_envs: int = 2048,
                 recreate_every: int = 8, render_backend: str = "none", sim_config: dict | None = None,
                 device: str | None = None, progress: bool = True, render_dir: str | None = None):
        if not isinstance(task, dict) or "session" not in task:
            raise ValueError("task must be a plain dict with a 'session' node (OmegaConf.to_container it)")
        if backend not in BACKENDS:
            raise GpuEvaluatorError(f"evaluator.backend={backend} is not one of {', '.join(BACKENDS)}")
        if int(max_envs) < 1 or int(recreate_every) < 1:
            raise GpuEvaluatorError(f"evaluator.max_envs and evaluator.recreate_every must be >= 1, got {max_envs} "
                                    f"and {recreate_every}")
        if render_dir:
            raise GpuEvaluatorError("render=true writes a picture per trial, which evaluator=gpu does not: "
                                    "use evaluator=sim to render")
        check_batched(task, policy, backend, max_envs)
        self.backend, self.max_envs = backend, int(max_envs)
        self.device = device or ("cuda" if backend == "physx_cuda" else "cpu")
        if backend == "physx_cuda":
            _require_cuda()
        self.task, self.policy_cfg = task, policy
        from grt.tasks import session_class

        self.session_class = session_class(task)
        self.recreate_every, self.render_backend = int(recreate_every), str(render_backend)
        self.sim_config = dict(sim_config or {})
        self.collision = make_collision(collision, nominal, coacd, cache_dir, max_hull_vertices)
        self.collision_kind, self.progress = collision, progress
        self.policy = self._build_policy(policy)
        self.session, self._uses = None, 0
        self.collision_s = self.run_s = 0.0
        self.stats = {"batches": 0, "sub_scenes": 0, "envs_built": 0, "build_s": 0.0, "episodes_s": 0.0,
                      "gpu_free_mb": [], "hulls": 0, "max_hull_inflation_mm": 0.0}

    # ------------------------------------------------------------------------------- interface
    @classmethod
    def preflight(cls, task: dict, policy: dict, backend: str = "physx_cuda", max_envs: int = 2048, **_) -> None:
        """Refuse, before a run writes anything, what this evaluator cannot run (see :func:`check_batched`)."""
        check_batched(task, policy, backend, max_envs)
        if backend == "physx_cuda":
            _require_cuda()

    def start(self, say=lambda line: print(line, flush=True)) -> float:
        """Nothing to start ahead: the env is built for the first population's size; says so once."""
        if say is not None and self.session is None:
            say(f"evaluator=gpu: {self.backend}, up to {self.max_envs} sub-scene{'s' * (self.max_envs != 1)} per env; the simulator is built "
                "for each population (a few seconds per rebuild)")
        return 0.0

    def evaluate(self, meshes: list[trimesh.Trimesh], seeds: list[int], parts: list[list[np.ndarray]] | None = None,
                 policy: dict | None = None,
                 on_result: Callable[[int, CandidateResult], None] | None = None) -> list[CandidateResult]:
        """Score every mesh on the same seeds; see :meth:`grt.evaluators.base.Evaluator.evaluate`.

        ``parts``: each mesh's convex parts when known; ``policy``: another policy config for this call;
        ``on_result(i, result)``: called as soon as mesh ``i``'s trials are all in (after its last batch).
        """
        seeds = [int(s) for s in seeds]
        if not seeds:
            raise ValueError("seeds is empty: give at least one episode seed")
        if len(set(seeds)) != len(seeds):
            raise ValueError("seeds must be distinct (a repeated seed repeats the same episode)")
        if parts is not None and len(parts) != len(meshes):
            raise ValueError(f"parts must give one list per mesh ({len(meshes)}), got {len(parts)}")
        parts, errors = self._collision_parts(meshes) if parts is None else (list(parts), {})
        errors.update(self._refused(meshes, errors))
        acting = self.policy if policy is None else self._build_policy(policy)
        trials: list[dict[int, TrialOutcome]] = [{} for _ in meshes]
        wall = np.zeros(len(meshes))
        results: list[CandidateResult | None] = [None] * len(meshes)

        def finish(i: int) -> None:
            results[i] = CandidateResult.from_trials([trials[i][s] for s in seeds], wall[i],
                                                     {"collision": self.collision_kind, "parts": len(parts[i]),
                                                      "evaluator": "gpu"})
            if on_result is not None:
                on_result(i, results[i])

        for i, reason in errors.items():
            trials[i] = {s: sim_error(s, reason) for s in seeds}
            finish(i)
        batches = plan_batches([i for i in range(len(meshes)) if i not in errors], seeds, self.max_envs)
        bar = progress_bar(sum(b.real for b in batches), "trials", "trial", leave=False) if (
            self.progress and batches) else None
        start = time.perf_counter()
        try:
            for batch in batches:
                outcomes, seconds = self._run_batch(batch, meshes, parts, acting)
                for k in range(batch.real):
                    c = batch.candidates[k]
                    trials[c][batch.seeds[k]] = outcomes[k]
                    wall[c] += seconds / len(batch)
                    if results[c] is None and len(trials[c]) == len(seeds):
                        finish(c)
                if bar is not None:
                    bar.update(batch.real)
        finally:
            self.run_s = time.perf_counter() - start
            if bar is not None:
                bar.close()
        return results

    def evaluate_each(self, meshes: list[trimesh.Trimesh], seeds: list[int],
                      on_result: Callable[[int, CandidateResult], None]) -> list[CandidateResult]:
        """:meth:`evaluate` with a call-back per mesh as soon as its last batch is done."""
        return self.evaluate(meshes, seeds, on_result=on_result)

    def collision_parts(self, mesh: trimesh.Trimesh) -> list[np.ndarray]:
        return self.collision.parts(mesh)

    def backend_info(self) -> dict:
        """The ``evaluator`` block of ``summary.json``: where and how the trials ran."""
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

    # -------------------------------------------------------------------------------- helpers
    def _run_batch(self, batch: Batch, meshes, parts, policy) -> tuple[list[TrialOutcome], float]:
        """One batch: (re)build the env around its objects, run every sub-scene's episode."""
        begin = time.perf_counter()
        session = self._session(len(batch))
        order, assignment = objects_of(batch)
        session.load_objects([(meshes[c], parts[c]) for c in order], assignment)
        built = time.perf_counter()
        outcomes = session.run_episodes(list(batch.seeds), policy)
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
        from hydra.utils import instantiate

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

    def _build_policy(self, policy: dict):
        from hydra.utils import get_object, instantiate

        target = get_object(str(policy["_target_"]))
        extra = {"device": self.device} if "device" not in policy and _accepts(target, "device") else {}
        return instantiate(policy, **extra)

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

    def _refused(self, meshes: list[trimesh.Trimesh], skip: dict[int, str]) -> dict[int, str]:
        """Why the task would not load a mesh (:meth:`BatchedEpisodes.check_candidate`), by index: such a
        candidate gets no sub-scene, its trials are ``sim_error``s as a CPU worker records them."""
        kwargs = {k: v for k, v in self.task["session"].items() if k != "_target_"}
        errors = {}
        for i, mesh in enumerate(meshes):
            if i in skip:
                continue
            try:
                self.session_class.check_candidate(mesh, **kwargs)
            except Exception as exc:  # noqa: BLE001 - whatever the task refuses
                errors[i] = f"load_object failed: {type(exc).__name__}: {exc}"
        return errors


def _require_cuda() -> None:
    import torch

    if not torch.cuda.is_available():
        raise GpuEvaluatorError("evaluator=gpu simulates on a CUDA GPU (physx_cuda), and torch sees none here: use "
                                "evaluator=sim (CPU workers), or evaluator.backend=physx_cpu evaluator.max_envs=1 to run "
                                "this evaluator's path one sub-scene at a time")
