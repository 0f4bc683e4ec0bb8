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
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from grt.errors import UserError

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
    """The result of one seeded trial (built by :func:`trial_outcome` alone).

    Attributes:
        seed: the episode seed (object pose randomization and the policy's sampling).
        score: the task metric of this trial (1.0 / 0.0 for binary tasks).
        success: whether the task succeeded (the mode is ``success``).
        mode: ``success`` or a failure mode, one of the task's :attr:`TaskSession.failure_modes`.
        info: JSON-serializable details (timings in seconds, grasp width in meters, ...).
    """

    seed: int
    score: float
    success: bool
    mode: str
    info: dict[str, Any] = field(default_factory=dict)


def trial_outcome(seed: int, mode: str, score: float, info: dict | None = None) -> TrialOutcome:
    """The one way a :class:`TrialOutcome` is made: ``success`` is ``mode == "success"``."""
    return TrialOutcome(seed=int(seed), score=float(score), success=mode == SUCCESS, mode=str(mode),
                        info=dict(info or {}))


def sim_error(seed: int, reason: str, **info) -> TrialOutcome:
    """A trial that produced no outcome because the simulation failed; ``info["error"]`` says why."""
    return trial_outcome(seed, SIM_ERROR, 0.0, {"error": reason, **info})


#: the objects a session loads: a mesh (m) and its convex parts ``(K, 3)`` each; ``(None, None)``: the task's
#: own stock object (a ManiSkill task's stock actor; a task without one refuses it)
Objects = list[tuple[trimesh.Trimesh | None, list[np.ndarray] | None]]


class Episodes:
    """The episodes of one :meth:`TaskSession.run_episodes` call, one per sub-scene, as a task plays them.

    Attributes:
        seeds: sub-scene ``i``'s episode seed.
        steps: ``(N,)`` control steps sub-scene ``i``'s episode took.
        info: per sub-scene, what its episode recorded so far (kept when it ends in a failure).
    """

    def __init__(self, seeds: Sequence[int]):
        self.seeds = [int(s) for s in seeds]
        self.steps = np.zeros(len(self.seeds), np.int64)
        self.info: list[dict] = [{} for _ in self.seeds]
        self._ended: list[tuple[str, float] | None] = [None] * len(self.seeds)

    @property
    def running(self) -> np.ndarray:
        """``(N,)`` whether sub-scene ``i``'s episode has not ended yet."""
        return np.array([e is None for e in self._ended], bool)

    def end(self, i: int, mode: str, score: float, info: dict | None = None) -> None:
        """Sub-scene ``i``'s episode ended in ``mode`` with ``score``; ``info``: the task's state at its end."""
        self._ended[i] = (mode, float(score))
        if info is not None:
            self.info[i] = dict(info)

    def fail(self, i: int, reason: str) -> None:
        """Sub-scene ``i``'s simulation failed (``reason``: ``"Type: message"``): a ``sim_error``."""
        self._ended[i] = (SIM_ERROR, 0.0)
        self.info[i] = {**self.info[i], "error": reason}

    def fail_running(self, reason: str) -> None:
        """Every episode still running failed (an exception of the simulator or of the policy)."""
        for i in np.flatnonzero(self.running):
            self.fail(int(i), reason)

    def outcomes(self, wall_s: float) -> list[TrialOutcome]:
        """One outcome per sub-scene: its mode and score, ``info`` as recorded (floats to 6 digits) with
        ``steps`` and ``wall_s`` (the call's seconds over its sub-scenes)."""
        out = []
        for seed, ended, info, steps in zip(self.seeds, self._ended, self.info, self.steps, strict=True):
            mode, score = ended if ended is not None else (SIM_ERROR, 0.0)
            info = {k: (round(v, 6) if isinstance(v, float) else v) for k, v in info.items()}
            out.append(trial_outcome(seed, mode, score, {**info, "steps": int(steps), "wall_s": wall_s}))
        return out


class TaskSession(ABC):
    """One environment, many objects, many trials. Subclasses take plain typed arguments.

    Every trial of every task runs through one protocol, :meth:`run_episodes`: the env's ``num_envs``
    sub-scenes (one on the CPU, many in a GPU simulation) each run one seeded episode on the object loaded
    there, and each ends in a :class:`TrialOutcome`. A task says how its episodes are played
    (:meth:`_play`: a closed-loop policy stepped every control step, a policy that drives the env itself, a
    planned grasp) and how objects are loaded (:meth:`load_objects`).

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
    #: parallel sub-scenes of the session's env: one episode each per :meth:`run_episodes`.
    num_envs: int = 1
    #: the policy under test (``None`` in a learning worker).
    policy = None

    @classmethod
    def max_sub_scenes(cls, sim_backend: str) -> int | None:
        """The most sub-scenes one env of this session can have on ``sim_backend`` (``None``: no limit):
        one, unless the task runs its episodes batched (:class:`grt.tasks.batched.EpisodeSession`)."""
        return 1

    @classmethod
    def check_object(cls, mesh: trimesh.Trimesh, **session_kwargs) -> None:
        """Raise a user error (message naming the fix) if this task cannot use ``mesh`` at all."""
        return None

    @classmethod
    def check_candidate(cls, mesh: trimesh.Trimesh, **session_kwargs) -> None:
        """Raise if :meth:`load_objects` would refuse ``mesh``, so that an evaluator can count one candidate's
        trials as failed before it shares an env with the others."""
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
    def load_objects(self, objects: Objects, assignment: Sequence[int]) -> None:
        """Sub-scene ``i`` holds ``objects[assignment[i]]`` from the next episode on.

        Args:
            objects: the distinct objects, each a visual mesh (meters, z up, resting on z = 0, centered in x/y)
                and its convex collision parts, each a ``(K, 3)`` vertex array in the mesh's frame (m).
            assignment: ``num_envs`` indices into ``objects``.

        Raises:
            ValueError: if an object has no parts or a part does not build into a collision shape.
        """

    def load_object(self, mesh: trimesh.Trimesh | None, parts: list[np.ndarray] | None) -> None:
        """Every sub-scene holds ``mesh`` with its convex ``parts`` (see :meth:`load_objects`)."""
        self.load_objects([(mesh, parts)], [0] * self.num_envs)

    @abstractmethod
    def _play(self, episodes: Episodes) -> None:
        """Play sub-scene ``i``'s episode with ``episodes.seeds[i]`` on its object until each has ended
        (:meth:`Episodes.end`, :meth:`Episodes.fail`), counting its control steps in ``episodes.steps``.
        An exception ends every episode still running as a ``sim_error``."""

    def run_episodes(self, seeds: Sequence[int]) -> list[TrialOutcome]:
        """Run sub-scene ``i``'s episode with ``seeds[i]`` (``len(seeds) == num_envs``); one outcome each.

        Args:
            seeds: one episode seed per sub-scene (repeats allowed: two objects on the same episode).

        Returns:
            One :class:`TrialOutcome` per sub-scene, in order; ``info`` the task's record of the episode (its
            state at the last step), ``steps`` and ``wall_s`` (the call's seconds over ``num_envs``). A physics
            failure, a non-finite state or a policy's unusable output is that episode's ``sim_error``.
        """
        if len(seeds) != self.num_envs:
            raise ValueError(f"run_episodes needs one seed per sub-scene ({self.num_envs}), got {len(seeds)}")
        episodes = Episodes(seeds)
        start = time.perf_counter()
        try:
            self._play(episodes)
        except Exception as err:  # physics or policy failures must not pass silently
            episodes.fail_running(f"{type(err).__name__}: {err}")
        return episodes.outcomes((time.perf_counter() - start) / self.num_envs)

    def run_trial(self, seed: int) -> TrialOutcome:
        """Run one episode on the loaded object (a session of one sub-scene); deterministic given ``seed``."""
        if self.num_envs != 1:
            raise ValueError(f"run_trial runs one episode; this session has {self.num_envs} sub-scenes: "
                             "use run_episodes(seeds)")
        return self.run_episodes([seed])[0]

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the simulator."""

    def __enter__(self) -> TaskSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def init_default(cls: type, name: str):
    """The default of argument ``name`` of ``cls.__init__`` (what a session gets when its config omits it)."""
    import inspect

    return inspect.signature(cls.__init__).parameters[name].default
