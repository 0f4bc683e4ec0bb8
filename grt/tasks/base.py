"""Task sessions: what the evaluator drives, one simulator per worker process.

A :class:`TaskSession` owns one simulated environment for its whole life. The evaluator swaps the
object (``load_object``: a reconfigure, tens of milliseconds) and then runs seeded trials
(``run_trial``), each ending in a :class:`TrialOutcome` with a named failure mode — a trial never
fails or succeeds silently.

Each session class declares its own failure modes in
:attr:`TaskSession.failure_modes` (``GraspSession``: ``no_grasp_found``, ``unreachable``, ``missed``,
``dropped_lift``, ``dropped_shake``; ``InsertionSession``: ``jammed``, ``misaligned``, ``dropped``,
``timeout``; ``DrawerSession``: ``missed_handle``, ``slipped``, ``partial_open``, ``timeout``); every task
has the :data:`COMMON_MODES`:

- ``success``: the task's success condition holds at the end of the trial.
- ``sim_error``: the simulation itself failed (NaN state, object flying away, a physics exception).

A task module's docstring explains its own modes as such a list; :func:`mode_meanings` reads them there, so
``report.html`` explains each mode it shows from the one text a developer reads.
"""

from __future__ import annotations

import ast
import importlib.util
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from grt.errors import UserError
from grt.policies.base import check_actions

SUCCESS, SIM_ERROR = "success", "sim_error"
#: The trial modes of every task: its success condition held, or the simulation itself failed.
COMMON_MODES = (SUCCESS, SIM_ERROR)
#: The worker pool's default ``trial_timeout`` (s) for a task whose session gives no bound of its own
#: (:meth:`TaskSession.trial_seconds` is ``None``: a user's task, unless it says).
FALLBACK_TRIAL_TIMEOUT = 600.0
#: A task's default ``trial_timeout`` is this many times the longest a trial of it takes (its
#: :meth:`TaskSession.trial_seconds`, itself from worst cases measured on a loaded machine).
TRIAL_TIMEOUT_MARGIN = 3.0


_MODE_ITEM = re.compile(r"^- ``(\w+)``: (.*)$")


def _docstring_items(module: str) -> dict[str, str]:
    """The ``- ``mode``: text`` items of a module's docstring (read from its source, not imported: the task
    modules import the simulator), each with its continuation lines, without the trailing ``;``/``.``."""
    try:
        spec = importlib.util.find_spec(module)
        source = spec.loader.get_source(module) if spec is not None and spec.loader is not None else None
        doc = ast.get_docstring(ast.parse(source)) if source else None
    except (ImportError, ValueError, SyntaxError, AttributeError):
        return {}
    items: dict[str, str] = {}
    current = None
    for line in (doc or "").splitlines():
        match = _MODE_ITEM.match(line)
        if match:
            current = match.group(1)
            items[current] = match.group(2)
        elif current and line.startswith("  ") and line.strip():
            items[current] += " " + line.strip()
        else:
            current = None
    return {k: v.replace("``", "").strip().rstrip(";.") for k, v in items.items()}


def mode_meanings(session_target: str | None) -> dict[str, str]:
    """What each trial mode of a task means, one line each: ``{mode: meaning}`` from the docstrings of the
    session's module (``session_target``: ``task.session._target_``, e.g. ``grt.tasks.grasp.GraspSession``) and
    of this module (the :data:`COMMON_MODES`); a mode the docstrings do not list is absent."""
    meanings = _docstring_items(__name__)
    if session_target and "." in str(session_target):
        meanings.update(_docstring_items(str(session_target).rsplit(".", 1)[0]))
    return meanings


class TaskInputError(UserError):
    """An object or task setting the task cannot use (a user error: the message names the fix)."""


@dataclass
class TrialOutcome:
    """The result of one seeded trial.

    Attributes:
        seed: the episode seed (object pose randomization and the policy's sampling).
        score: the task metric of this trial (1.0 / 0.0 for binary tasks).
        success: whether the task succeeded.
        mode: ``success`` or a failure mode, one of the task's :attr:`TaskSession.failure_modes`.
        info: JSON-serializable details (timings in seconds, grasp width in meters, ...).
    """

    seed: int
    score: float
    success: bool
    mode: str
    info: dict[str, Any] = field(default_factory=dict)


class TaskSession(ABC):
    """One environment, many objects, many trials. Subclasses take plain typed arguments.

    Usage (what an evaluator worker does)::

        session = hydra.utils.instantiate(task_cfg.session, policy=policy)
        session.load_object(mesh, parts)
        outcomes = [session.run_trial(seed) for seed in seeds]
        session.close()
    """

    #: Name of the task metric; ``success`` means binary (score = float(success)).
    score_name: str = "success"
    #: Every mode a trial of this task can end in: :data:`COMMON_MODES` and the task's own failure modes.
    failure_modes: tuple[str, ...] = COMMON_MODES

    #: the kinds of policy (keys of :data:`grt.policies.base.POLICY_KINDS`) this task runs; empty: any.
    policy_kinds: tuple[str, ...] = ()

    #: observation groups this task produces (name -> shape without the batch dimension).
    obs_spec: dict[str, tuple[int, ...]] = {}
    num_actions: int = 0

    @classmethod
    def check_object(cls, mesh: trimesh.Trimesh, **session_kwargs) -> None:
        """Raise a user error (message naming the fix) if this task cannot use ``mesh`` at all."""
        return None

    @classmethod
    def observation_spec(cls, **session_kwargs) -> dict[str, tuple[int, ...]]:
        """The observation groups a session built with these arguments produces (no simulator needed)."""
        return dict(cls.obs_spec)

    @classmethod
    def trial_seconds(cls, **session_kwargs) -> float | None:
        """The longest one trial of a session built with ``session_kwargs`` takes, in seconds, with an
        in-process policy: its episode's length times worst-case step times measured on a loaded machine
        (``scripts/step_times.py``, docs/benchmarks.md "Trial timeouts"), or ``None`` when the task does not say.
        The worker pool's default ``trial_timeout`` is :data:`TRIAL_TIMEOUT_MARGIN` times it
        (:func:`grt.evaluators.sim.default_trial_timeout`)."""
        return None

    @abstractmethod
    def load_object(self, mesh: trimesh.Trimesh, parts: list[np.ndarray]) -> None:
        """Rebuild the scene around a new object.

        Args:
            mesh: the visual mesh, meters, z up, resting on z = 0, centered in x/y.
            parts: convex collision parts, each a ``(K, 3)`` vertex array in the mesh's frame (m).

        Raises:
            ValueError: if ``parts`` is empty or a part does not build into a collision shape.
        """

    @abstractmethod
    def run_trial(self, seed: int) -> TrialOutcome:
        """Run one episode on the loaded object; deterministic given ``seed``."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the simulator."""

    def __enter__(self) -> TaskSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class EpisodeSession(TaskSession):
    """A task whose policy acts every control step: one session serves evaluation *and* learning.

    The same methods drive a red-team trial (:meth:`run_trial`) and a reinforcement-learning worker
    (:meth:`reset` / :meth:`step`, used by :class:`grt.rl.vec_env.TaskVecEnv`), so a policy is trained
    and red-teamed in the very same environment. Subclasses build the ManiSkill env and implement
    :meth:`observe`, :meth:`judge` and :meth:`load_object`.

    Args:
        policy: a :class:`grt.policies.base.BatchedPolicy` (``None`` in a learning worker).
        max_steps: control steps per episode (the episode ends earlier at success).
        rebuild_each_trial: rebuild the scene before every evaluation trial (~30 ms), so that an
            outcome depends only on (object, seed), whatever ran before in this process.
    """

    policy_kinds = ("closed_loop",)
    #: the task's name (``conf/task/<name>.yaml``), checked against a learned policy's training task.
    task_name: str = ""
    #: worst cases (s) measured on a loaded machine: one control step (the policy's act, the simulation and the
    #: observation; the slowest trial's mean), a trial's reset (the scene rebuilt); ``None``: not measured
    STEP_S: float | None = None
    RESET_S: float = 0.0
    #: the gymnasium env a subclass builds (``gym.make``), closed and rendered by the methods below.
    env = None

    def __init__(self, policy=None, max_steps: int = 256, rebuild_each_trial: bool = True):
        self.policy, self.max_steps, self.rebuild_each_trial = policy, int(max_steps), bool(rebuild_each_trial)
        self.steps = 0

    @classmethod
    def trial_seconds(cls, **session_kwargs) -> float | None:
        """The reset and ``max_steps`` control steps at the measured worst case (:attr:`STEP_S`,
        :attr:`RESET_S`); ``None`` for a task that measured none (see :meth:`TaskSession.trial_seconds`)."""
        if cls.STEP_S is None:
            return None
        return cls.RESET_S + int(session_kwargs.get("max_steps") or init_default(cls, "max_steps")) * cls.STEP_S

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
    @abstractmethod
    def _reset_env(self, seed: int, rebuild: bool) -> None:
        """Reset the env with ``seed`` (rebuilding the scene when asked)."""

    @abstractmethod
    def _step_env(self, action: np.ndarray) -> tuple[float, bool, dict]:
        """Apply one action; returns ``(reward, success, info)``."""

    @abstractmethod
    def observe(self) -> dict[str, np.ndarray]:
        """The policy's observation groups, unbatched (shapes as :attr:`obs_spec`)."""

    @abstractmethod
    def judge(self, success: bool, info: dict) -> str:
        """The trial's mode (``success`` or a failure mode) from the final state."""

    def hopeless(self, info: dict) -> bool:
        """End an evaluation trial early: nothing the policy does can succeed any more (e.g. the
        object left the gripper). Learning episodes always run to success or the time limit."""
        return False

    def score(self, success: bool, info: dict) -> float:
        """The trial's score: ``float(success)`` for binary tasks; continuous tasks override."""
        return float(success)

    # --- learning interface --------------------------------------------------------------------------
    def reset(self, seed: int, rebuild: bool = False) -> dict[str, np.ndarray]:
        """Start an episode; returns the first observation."""
        self._reset_env(int(seed), rebuild)
        self.steps = 0
        return self.observe()

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        """One control step: ``(obs, reward, terminated, truncated, info)``; terminated = success."""
        action = np.clip(np.asarray(action, np.float32).reshape(self.num_actions), -1.0, 1.0)
        reward, success, info = self._step_env(action)
        self.steps += 1
        info["success"] = bool(success)
        return self.observe(), float(reward), bool(success), self.steps >= self.max_steps, info

    # --- evaluation protocol -------------------------------------------------------------------------
    def run_trial(self, seed: int) -> TrialOutcome:
        import time

        start = time.perf_counter()
        info: dict = {}
        try:
            obs = self.reset(seed, rebuild=self.rebuild_each_trial)
            self.policy.reset(seed)
            done, success = False, False
            while not done:  # a NaN or misshapen action: a sim_error naming the policy, from the first step on
                action = check_actions(self.policy.act({k: v[None] for k, v in obs.items()}), (1, self.num_actions),
                                       self.policy)[0]
                obs, _, success, truncated, info = self.step(action)
                self._check(info)
                done = success or truncated or self.hopeless(info)
            mode = self.judge(success, info)
            score = self.score(success, info)
        except Exception as err:  # physics failures must not pass silently
            mode, score, success = SIM_ERROR, 0.0, False
            info = {"error": f"{type(err).__name__}: {err}"}
        info = {k: (round(v, 6) if isinstance(v, float) else v) for k, v in info.items()}
        info.update(steps=self.steps, wall_s=time.perf_counter() - start)
        return TrialOutcome(seed=int(seed), score=float(score), success=mode == "success", mode=mode, info=info)

    def _check(self, info: dict) -> None:
        """Raise on a non-finite state (subclasses add runaway checks)."""
        for k, v in info.items():
            if isinstance(v, float) and not np.isfinite(v):
                raise FloatingPointError(f"non-finite {k} in the simulation state")


def init_default(cls: type, name: str):
    """The default of argument ``name`` of ``cls.__init__`` (what a session gets when its config omits it)."""
    import inspect

    return inspect.signature(cls.__init__).parameters[name].default
