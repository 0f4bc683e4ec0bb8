"""Batched episodes: one env, ``num_envs`` sub-scenes, each with its own object and episode seed.

A :class:`BatchedEpisodes` session runs many trials at once in one ManiSkill env: on ``physx_cuda`` every
parallel sub-scene holds its own object (ManiSkill's per-sub-scene builders, then ``Actor.merge``), and
one :meth:`BatchedEpisodes.run_episodes` call runs sub-scene ``i``'s episode with ``seeds[i]`` until each
has ended. The task's observations, success and failure flags come from the env's batched
``(num_envs, ...)`` tensors; the episode protocol is :meth:`grt.tasks.base.EpisodeSession.run_trial`'s, per
sub-scene:

- a sub-scene's episode ends at success, at ``max_steps``, when :meth:`hopeless_batch` says so, or at a
  simulation failure (:meth:`check_batch`: a non-finite state, a runaway object); its outcome is judged
  from its state *at that step* (the task's :meth:`~grt.tasks.base.EpisodeSession.judge` and
  :meth:`~grt.tasks.base.EpisodeSession.score`), and it then idles (zero actions) while the others run;
- an exception of the simulator or of the policy ends every sub-scene still running as ``sim_error``.

With ``num_envs=1`` (``physx_cpu``, what every CPU worker runs) this *is* the task's ``run_trial``: the
single-env hooks of :class:`grt.tasks.base.EpisodeSession` (``_reset_env``, ``_step_env``, ``observe``) are
the batched ones at sub-scene 0, so a CPU trial and sub-scene ``i`` of a GPU batch start from the same
seeded state (the same socket pose, arm noise, ...) and are judged by the same code.
"""

from __future__ import annotations

import time
from abc import abstractmethod
from collections.abc import Sequence

import numpy as np
import trimesh

from grt.policies.base import PolicyOutputError, check_actions, policy_name
from grt.tasks.base import SIM_ERROR, TrialOutcome

Objects = list[tuple[trimesh.Trimesh, list[np.ndarray]]]


def to_numpy(value) -> np.ndarray:
    """A torch tensor (any device) or array as a numpy array (no copy on the CPU)."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value)


def info_at(info: dict[str, np.ndarray], i: int) -> dict:
    """Sub-scene ``i``'s entry of a batched info dict, as Python scalars (floats, bools)."""
    return {k: v[i].item() for k, v in info.items()}


def policy_reset(policy, seeds: Sequence[int]) -> None:
    """Start a batch of episodes: ``policy.reset_batch(seeds)`` when it has one, else ``reset(seeds[0])``
    (for one episode exactly the single-trial call; a sampled policy's noise is then seeded per batch)."""
    batch = getattr(policy, "reset_batch", None)
    if batch is not None:
        batch([int(s) for s in seeds])
    else:
        policy.reset(int(seeds[0]))


class BatchedEpisodes:
    """Mixin for an :class:`grt.tasks.base.EpisodeSession` whose env runs ``num_envs`` sub-scenes at once.

    A subclass implements the batched hooks (:meth:`load_objects`, :meth:`_reset_batch`,
    :meth:`_step_batch`, :meth:`observe_batch`) and may refine :meth:`check_batch`,
    :meth:`hopeless_batch` and :meth:`start_errors`; this class derives the single-env hooks from them.
    It comes first in the bases (``class InsertionSession(BatchedEpisodes, EpisodeSession)``).
    """

    num_envs: int = 1

    @classmethod
    def max_sub_scenes(cls, sim_backend: str) -> int | None:
        """The most sub-scenes one env of this session can have on ``sim_backend`` (``None``: no limit):
        ManiSkill's CPU simulation runs one (``physx_cpu`` refuses ``num_envs > 1``)."""
        return 1 if sim_backend == "physx_cpu" else None

    @classmethod
    def check_candidate(cls, mesh: trimesh.Trimesh, **session_kwargs) -> None:
        """Raise if :meth:`load_objects` would refuse ``mesh`` (as ``load_object`` would on the CPU), so that an
        evaluator can count one candidate's trials as failed before it shares an env with the others."""
        return None

    # --- what a subclass provides --------------------------------------------------------------------
    @abstractmethod
    def load_objects(self, objects: Objects, assignment: Sequence[int]) -> None:
        """Sub-scene ``i`` holds ``objects[assignment[i]]`` (mesh, convex parts) from the next reset on.

        Args:
            objects: the distinct objects, each a mesh (m) and its convex parts ``(K, 3)``.
            assignment: ``num_envs`` indices into ``objects``.
        """

    @abstractmethod
    def _reset_batch(self, seeds: Sequence[int], rebuild: bool) -> None:
        """Reset every sub-scene, sub-scene ``i`` with ``seeds[i]`` (rebuilding the scene when asked)."""

    @abstractmethod
    def _step_batch(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Apply actions ``(N, A)``; returns rewards ``(N,)``, success flags ``(N,)`` and the task's state
        ``{key: (N,)}`` (floats and bools; the keys of a trial's ``info``)."""

    @abstractmethod
    def observe_batch(self) -> dict[str, np.ndarray]:
        """The policy's observation groups, batched ``{group: (N, ...)}``."""

    def start_errors(self) -> list[str | None]:
        """Per sub-scene, why its episode could not start (e.g. no IK solution), or ``None``."""
        return [None] * self.num_envs

    def check_batch(self, info: dict[str, np.ndarray]) -> list[str | None]:
        """Per sub-scene, the simulation failure its state shows (``"FloatingPointError: ..."``), or ``None``.

        The first non-finite float key in ``info``'s order names it, as
        :meth:`grt.tasks.base.EpisodeSession._check` does; subclasses add runaway checks after it.
        """
        errors: list[str | None] = [None] * len(next(iter(info.values())))
        for key, value in info.items():
            if value.dtype.kind != "f":
                continue
            for i in np.flatnonzero(~np.isfinite(value)):
                if errors[i] is None:
                    errors[i] = f"FloatingPointError: non-finite {key} in the simulation state"
        return errors

    def clip_actions(self, actions: np.ndarray) -> np.ndarray:
        """Actions ``(N, A)`` clipped to what the env takes (GRT's tasks: [-1, 1], as ``EpisodeSession.step``)."""
        return np.clip(actions, -1.0, 1.0)

    def hull_tally(self) -> dict:
        """The last scene build's convex hulls: ``parts`` built and the most PhysX grew one (``max_inflation_m``)."""
        return {}

    def hopeless_batch(self, info: dict[str, np.ndarray]) -> np.ndarray:
        """Per sub-scene, whether nothing the policy does can succeed any more (ends an evaluation early)."""
        return np.zeros(len(next(iter(info.values()))), bool)

    # --- the single-env hooks of EpisodeSession, at sub-scene 0 ---------------------------------------
    def load_object(self, mesh: trimesh.Trimesh, parts: list[np.ndarray]) -> None:
        """Every sub-scene holds ``mesh`` (with its convex parts)."""
        self.load_objects([(mesh, parts)], [0] * self.num_envs)

    def _reset_env(self, seed: int, rebuild: bool) -> None:
        self._reset_batch([int(seed)] * self.num_envs, rebuild)
        error = self.start_errors()[0]
        if error is not None:  # the learning workers skip a start the robot cannot reach
            raise RuntimeError(error.split(": ", 1)[-1])

    def _step_env(self, action: np.ndarray) -> tuple[float, bool, dict]:
        reward, success, info = self._step_batch(np.broadcast_to(action, (self.num_envs, len(action))))
        return float(reward[0]), bool(success[0]), info_at(info, 0)

    def observe(self) -> dict[str, np.ndarray]:
        return {k: v[0] for k, v in self.observe_batch().items()}

    def run_trial(self, seed: int) -> TrialOutcome:
        if self.num_envs != 1:
            raise ValueError(f"run_trial runs one episode; this session has {self.num_envs} sub-scenes: "
                             "use run_episodes(seeds)")
        return self.run_episodes([seed])[0]

    # --- the evaluation protocol, batched ---------------------------------------------------------------
    def run_episodes(self, seeds: Sequence[int], policy=None) -> list[TrialOutcome]:
        """Run sub-scene ``i``'s episode with ``seeds[i]`` (``len(seeds) == num_envs``); one outcome each.

        Args:
            seeds: one episode seed per sub-scene (repeats allowed: two objects on the same episode).
            policy: a :class:`grt.policies.base.BatchedPolicy` (``None``: the session's).

        Returns:
            One :class:`TrialOutcome` per sub-scene, in order; ``info`` as a single trial's (the task's state
            at the episode's last step, ``steps``, ``wall_s``: the batch's seconds over ``num_envs``).
        """
        seeds = [int(s) for s in seeds]
        if len(seeds) != self.num_envs:
            raise ValueError(f"run_episodes needs one seed per sub-scene ({self.num_envs}), got {len(seeds)}")
        policy = self.policy if policy is None else policy
        start, n = time.perf_counter(), self.num_envs
        ended: list[tuple[str, float, dict] | None] = [None] * n
        steps = np.zeros(n, np.int64)

        def end_all(err: Exception) -> None:
            for i in range(n):
                if ended[i] is None:
                    ended[i] = (SIM_ERROR, 0.0, {"error": f"{type(err).__name__}: {err}"})

        try:
            self._reset_batch(seeds, self.rebuild_each_trial)
            self.steps = 0
            for i, error in enumerate(self.start_errors()):
                if error is not None:
                    ended[i] = (SIM_ERROR, 0.0, {"error": error})
            if any(e is None for e in ended):
                policy_reset(policy, seeds)
            while any(e is None for e in ended):
                self._run_step(policy, ended, steps)
        except Exception as err:  # physics or policy failures must not pass silently
            end_all(err)
        per_trial = (time.perf_counter() - start) / n
        outcomes = []
        for i, (mode, score, info) in enumerate(ended):
            info = {k: (round(v, 6) if isinstance(v, float) else v) for k, v in info.items()}
            info.update(steps=int(steps[i]), wall_s=per_trial)
            outcomes.append(TrialOutcome(seed=seeds[i], score=float(score), success=mode == "success", mode=mode,
                                         info=info))
        return outcomes

    def _actions(self, policy, obs: dict, running: np.ndarray, ended: list) -> np.ndarray:
        """The policy's ``(num_envs, num_actions)`` actions, clipped; an ended episode's are zero (it idles until
        the others end). A misshapen batch fails every running episode, a non-finite action its own: each a
        ``sim_error`` naming the policy (:func:`grt.policies.base.check_actions`), as a single trial's."""
        shape = (self.num_envs, self.num_actions)
        raw = policy.act(obs)
        try:
            actions = check_actions(raw, shape, policy)
        except PolicyOutputError as err:
            actions = np.asarray(raw, np.float64) if np.shape(raw) == shape else None
            if actions is None:
                raise
            for i in np.flatnonzero(running & ~np.isfinite(actions).all(axis=1)):
                ended[i] = (SIM_ERROR, 0.0, {"error": f"{type(err).__name__}: policy {policy_name(policy)} returned a "
                                                      f"non-finite action {actions[i].round(4).tolist()}"})
            running = np.array([e is None for e in ended])
            actions = np.where(np.isfinite(actions), actions, 0.0)
        actions = self.clip_actions(actions.astype(np.float32))
        actions[~running] = 0.0
        return actions

    def _run_step(self, policy, ended: list, steps: np.ndarray) -> None:
        """One control step of every sub-scene; ends (judges) those whose episode is over."""
        running = np.array([e is None for e in ended])
        obs = self.observe_batch()
        actions = self._actions(policy, obs, running, ended)
        running = np.array([e is None for e in ended])  # less any episode whose action was not finite
        reward, success, info = self._step_batch(actions)
        steps[running] += 1
        self.steps += 1
        errors = self.check_batch(info)
        over = success | self.hopeless_batch(info) | (self.steps >= self.max_steps)
        for i in np.flatnonzero(running):
            if errors[i] is not None:
                ended[i] = (SIM_ERROR, 0.0, {"error": errors[i]})
            elif over[i]:
                state = {**info_at(info, i), "success": bool(success[i])}
                ended[i] = (self.judge(bool(success[i]), state), self.score(bool(success[i]), state), state)
