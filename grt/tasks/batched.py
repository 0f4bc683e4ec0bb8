"""Closed-loop episodes, batched: one env, ``num_envs`` sub-scenes, each with its own object and episode seed.

An :class:`EpisodeSession` is a task whose policy acts every control step. One
:meth:`~grt.tasks.base.TaskSession.run_episodes` call runs sub-scene ``i``'s episode with ``seeds[i]`` until
each has ended; on ``physx_cuda`` every parallel sub-scene holds its own object (ManiSkill's per-sub-scene
builders, then ``Actor.merge``), on ``physx_cpu`` there is one (what every CPU worker runs). The task's
observations, success and failure flags come from the env's batched ``(num_envs, ...)`` tensors:

- a sub-scene's episode ends at success, at ``max_steps``, when :meth:`EpisodeSession.hopeless_batch` says so,
  or at a simulation failure (:meth:`EpisodeSession.check_batch`: a non-finite state, a runaway object); its
  outcome is judged from its state *at that step* (the task's :meth:`~EpisodeSession.judge` and
  :meth:`~EpisodeSession.score`), and it then idles (zero actions) while the others run;
- an exception of the simulator or of the policy ends every sub-scene still running as ``sim_error``.

The same session serves learning: :meth:`EpisodeSession.reset` / :meth:`EpisodeSession.step` (used by
:class:`grt.rl.vec_env.TaskVecEnv`) are the batched hooks at sub-scene 0, so a policy is trained and
red-teamed in the very same environment, and a CPU trial and sub-scene ``i`` of a GPU batch start from the
same seeded state (the same socket pose, arm noise, ...) and are judged by the same code.
"""

from __future__ import annotations

import gc
from abc import abstractmethod
from collections.abc import Sequence

import numpy as np

from grt.policies.base import PolicyOutputError, check_actions, policy_name
from grt.tasks.base import Episodes, Objects, TaskSession, init_default

__all__ = ["EpisodeSession", "Objects", "info_at", "policy_reset", "to_numpy"]


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


class EpisodeSession(TaskSession):
    """A task whose policy acts every control step, its episodes batched over the env's sub-scenes.

    A subclass builds the ManiSkill env (:meth:`_make_env` for GRT's own envs) and implements the batched
    hooks :meth:`load_objects`, :meth:`_step_batch` and :meth:`judge` (and, for other than GRT's envs,
    :meth:`_reset_batch` and :meth:`observe_batch`); it may refine :meth:`check_batch`,
    :meth:`hopeless_batch`, :meth:`start_errors`, :meth:`clip_actions` and :meth:`score`.

    Args:
        policy: a :class:`grt.policies.base.BatchedPolicy` (``None`` in a learning worker).
        max_steps: control steps per episode (the episode ends earlier at success).
        rebuild_each_trial: rebuild the scene before every evaluation trial (~30 ms), so that an
            outcome depends only on (object, seed), whatever ran before in this process.

    A subclass's ``num_envs``, ``sim_backend``, ``render_backend`` and ``sim_config`` arguments are ManiSkill's
    (:meth:`_make_env`; ``num_envs > 1`` needs ``physx_cuda``): the evaluators set them, a task config need not.
    """

    policy_kinds = ("closed_loop",)
    #: the task's name (``conf/task/<name>.yaml``), checked against a learned policy's training task.
    task_name: str = ""
    #: worst cases (s) measured on a loaded machine: one control step (the policy's act, the simulation and the
    #: observation; the slowest trial's mean), a trial's reset (the scene rebuilt); ``None``: not measured
    STEP_S: float | None = None
    RESET_S: float = 0.0
    #: the gymnasium env a subclass builds (``gym.make``), closed and rendered by the methods below, and its
    #: ManiSkill env (``env.unwrapped``)
    env = unwrapped = None

    def __init__(self, policy=None, max_steps: int = 256, rebuild_each_trial: bool = True):
        self.policy, self.max_steps, self.rebuild_each_trial = policy, int(max_steps), bool(rebuild_each_trial)
        self.steps = 0
        self._object_changed, self._obs = True, None

    @classmethod
    def max_sub_scenes(cls, sim_backend: str) -> int | None:
        """ManiSkill's CPU simulation runs one sub-scene per env (``physx_cpu`` refuses ``num_envs > 1``)."""
        return 1 if sim_backend == "physx_cpu" else None

    @classmethod
    def trial_seconds(cls, **session_kwargs) -> float | None:
        """The reset and ``max_steps`` control steps at the measured worst case (:attr:`STEP_S`,
        :attr:`RESET_S`); ``None`` for a task that measured none (see :meth:`TaskSession.trial_seconds`)."""
        if cls.STEP_S is None:
            return None
        return cls.RESET_S + int(session_kwargs.get("max_steps") or init_default(cls, "max_steps")) * cls.STEP_S

    def _make_env(self, env_id: str, num_envs: int, sim_backend: str, render_backend: str, sim_config: dict | None,
                  **env_kwargs) -> None:
        """Build one of GRT's own envs (``obs_mode=none``: the session reads ``task_obs``; a dense reward for
        learning) with ``num_envs`` sub-scenes, and keep the long-lived heap out of ManiSkill's ``gc.collect()``."""
        import gymnasium as gym

        self.num_envs = int(num_envs)
        self.env = gym.make(env_id, obs_mode="none", num_envs=self.num_envs, sim_backend=sim_backend,
                            render_backend=render_backend, sim_config=dict(sim_config or {}), reward_mode="dense",
                            **env_kwargs)
        self.unwrapped = self.env.unwrapped
        gc.collect()
        gc.freeze()  # ManiSkill's reconfigure runs gc.collect(): keep the long-lived heap out of it

    def set_policy(self, policy) -> None:
        """Run the next trials with ``policy`` (checked against this task's observations and actions)."""
        self.policy = policy
        self._check_policy()

    def _check_policy(self) -> None:
        """Refuse a policy that declares a different task or observation (see :func:`grt.tasks.check_policy`)."""
        check = getattr(self.policy, "check", None)
        if check is not None:
            check(self.task_name, self.obs_spec, self.num_actions)

    def close(self) -> None:
        if self.env is not None:
            self.env.close()

    def render(self, path: str) -> None:
        """Write a PNG of the scene as it is now (the env's human render camera)."""
        from PIL import Image

        image = self.env.unwrapped.render_rgb_array()
        Image.fromarray(np.asarray(image[0], dtype=np.uint8)).save(path)

    # --- what a subclass provides --------------------------------------------------------------------
    def load_objects(self, objects: Objects, assignment: Sequence[int]) -> None:
        """Sub-scene ``i`` holds ``objects[assignment[i]]`` from the next reset on (GRT's envs: ``set_objects``)."""
        self.unwrapped.set_objects(objects, list(assignment))
        self._object_changed = True

    def _reset_batch(self, seeds: Sequence[int], rebuild: bool) -> None:
        """Reset every sub-scene, sub-scene ``i`` with ``seeds[i]`` (rebuilding the scene when asked, or when the
        objects changed)."""
        self._obs, _ = self.env.reset(seed=[int(s) for s in seeds],
                                      options=dict(reconfigure=bool(rebuild or self._object_changed)))
        self._object_changed = False

    @abstractmethod
    def _step_batch(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """Apply actions ``(N, A)``; returns rewards ``(N,)``, success flags ``(N,)`` and the task's state
        ``{key: (N,)}`` (floats and bools; the keys of a trial's ``info``)."""

    def observe_batch(self) -> dict[str, np.ndarray]:
        """The policy's observation groups, batched ``{group: (N, ...)}`` (GRT's envs: ``task_obs``)."""
        return self.unwrapped.task_obs()

    @abstractmethod
    def judge(self, success: bool, info: dict) -> str:
        """The trial's mode (``success`` or a failure mode) from one sub-scene's final state."""

    def score(self, success: bool, info: dict) -> float:
        """The trial's score: ``float(success)`` for binary tasks; continuous tasks override."""
        return float(success)

    def start_errors(self) -> list[str | None]:
        """Per sub-scene, why its episode could not start (e.g. no IK solution), or ``None``."""
        return [None] * self.num_envs

    def check_batch(self, info: dict[str, np.ndarray]) -> list[str | None]:
        """Per sub-scene, the simulation failure its state shows (``"FloatingPointError: ..."``), or ``None``:
        the first non-finite float key in ``info``'s order names it; subclasses add runaway checks after it."""
        errors: list[str | None] = [None] * len(next(iter(info.values())))
        for key, value in info.items():
            if value.dtype.kind != "f":
                continue
            for i in np.flatnonzero(~np.isfinite(value)):
                if errors[i] is None:
                    errors[i] = f"FloatingPointError: non-finite {key} in the simulation state"
        return errors

    def hopeless_batch(self, info: dict[str, np.ndarray]) -> np.ndarray:
        """Per sub-scene, whether nothing the policy does can succeed any more (ends an evaluation early, e.g.
        the object left the gripper). Learning episodes always run to success or the time limit."""
        return np.zeros(len(next(iter(info.values()))), bool)

    def clip_actions(self, actions: np.ndarray) -> np.ndarray:
        """Actions ``(N, A)`` clipped to what the env takes (GRT's tasks: [-1, 1])."""
        return np.clip(actions, -1.0, 1.0)

    def hull_tally(self) -> dict:
        """The last scene build's convex hulls: ``parts`` built and the most PhysX grew one (``max_inflation_m``)."""
        return dict(getattr(self.unwrapped, "hull_tally", None) or {})

    # --- learning interface: the batched hooks at sub-scene 0 -----------------------------------------
    def reset(self, seed: int, rebuild: bool = False) -> dict[str, np.ndarray]:
        """Start an episode (every sub-scene with ``seed``); returns sub-scene 0's first observation.

        Raises:
            RuntimeError: the episode cannot start (the learning workers skip such a start).
        """
        self._reset_batch([int(seed)] * self.num_envs, rebuild)
        self.steps = 0
        error = self.start_errors()[0]
        if error is not None:
            raise RuntimeError(error.split(": ", 1)[-1])
        return self.observe()

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        """One control step of sub-scene 0: ``(obs, reward, terminated, truncated, info)``; terminated = success."""
        action = self.clip_actions(np.asarray(action, np.float32).reshape(1, self.num_actions))
        reward, success, info = self._step_batch(np.repeat(action, self.num_envs, axis=0))
        self.steps += 1
        info = {**info_at(info, 0), "success": bool(success[0])}
        return self.observe(), float(reward[0]), bool(success[0]), self.steps >= self.max_steps, info

    def observe(self) -> dict[str, np.ndarray]:
        """Sub-scene 0's observation groups, unbatched (shapes as :attr:`obs_spec`)."""
        return {k: v[0] for k, v in self.observe_batch().items()}

    # --- the evaluation protocol ------------------------------------------------------------------------
    def _play(self, episodes: Episodes) -> None:
        """Reset every sub-scene with its seed, then step them all with the policy until each has ended."""
        self._reset_batch(episodes.seeds, self.rebuild_each_trial)
        self.steps = 0
        for i, error in enumerate(self.start_errors()):
            if error is not None:
                episodes.fail(i, error)
        if episodes.running.any():
            policy_reset(self.policy, episodes.seeds)
        while episodes.running.any():
            self._run_step(episodes)

    def _actions(self, obs: dict, episodes: Episodes) -> np.ndarray:
        """The policy's ``(num_envs, num_actions)`` actions, clipped; an ended episode's are zero (it idles until
        the others end). A misshapen batch fails every running episode, a non-finite action its own: each a
        ``sim_error`` naming the policy (:func:`grt.policies.base.check_actions`)."""
        shape = (self.num_envs, self.num_actions)
        raw = self.policy.act(obs)
        try:
            actions = check_actions(raw, shape, self.policy)
        except PolicyOutputError as err:
            actions = np.asarray(raw, np.float64) if np.shape(raw) == shape else None
            if actions is None:
                raise
            for i in np.flatnonzero(episodes.running & ~np.isfinite(actions).all(axis=1)):
                episodes.fail(int(i), f"{type(err).__name__}: policy {policy_name(self.policy)} returned a "
                                      f"non-finite action {actions[i].round(4).tolist()}")
            actions = np.where(np.isfinite(actions), actions, 0.0)
        actions = self.clip_actions(actions.astype(np.float32))
        actions[~episodes.running] = 0.0
        return actions

    def _run_step(self, episodes: Episodes) -> None:
        """One control step of every sub-scene; ends (judges) those whose episode is over."""
        actions = self._actions(self.observe_batch(), episodes)
        running = episodes.running  # less any episode whose action was not finite
        _, success, info = self._step_batch(actions)
        episodes.steps[running] += 1
        self.steps += 1
        errors = self.check_batch(info)
        over = success | self.hopeless_batch(info) | (self.steps >= self.max_steps)
        for i in np.flatnonzero(running):
            if errors[i] is not None:
                episodes.fail(int(i), errors[i])
            elif over[i]:
                state = {**info_at(info, i), "success": bool(success[i])}
                episodes.end(int(i), self.judge(bool(success[i]), state), self.score(bool(success[i]), state), state)
