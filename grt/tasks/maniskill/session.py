"""Any registered ManiSkill env as a GRT task: one YAML names the env and the actor to deform.

:class:`ManiSkillSession` builds ``gym.make(env_id, obs_mode, control_mode, **env_kwargs)`` on the CPU
backend (one env per worker process; ManiSkill's ``(num_envs, ...)`` tensors are kept batched until the
last step, :meth:`ManiSkillSession.observe_batch`), swaps ONE actor for the candidate inside the env's own
configuration (:mod:`grt.tasks.maniskill.swap`), and judges a trial by the env's own ``evaluate()``:

- **score**: ``success`` (binary; the episode ends at the first step the env reports success, as
  ManiSkill's ``success_once``), or a continuous info key (``score: obj_to_goal_dist``,
  ``score_unit: m``), read at the end of the episode.
- **failure modes**, from an ordered list of the env's boolean info flags: a failed trial ends in the
  mode of the first flag that is false at its end (``[is_grasped, is_obj_placed]`` -> ``not_grasped``,
  ``not_placed``: ``is_`` and ``obj_`` dropped; a mapping names the modes itself); ``timeout`` when every
  flag held but the env never reported success; ``sim_error`` when the simulation failed (non-finite
  state, the actor thrown more than 5 m away, a physics exception).

**Policies.** Two kinds (:data:`grt.policies.base.POLICY_KINDS`):

- ``closed_loop`` (:class:`grt.policies.base.BatchedPolicy`: ``act(obs) -> actions``, rsl-rl
  checkpoints, ``policy=remote``, a user's class): the session resets the env and steps it with the
  policy's actions. Observations are the env's own: ``obs_mode=state`` gives one group ``state`` ``(D,)``,
  the flattened state ManiSkill's PPO baseline sees; a dict observation mode gives one group per leaf
  (``agent/qpos``, ...). Actions are the env's action space for the ``control_mode`` (``(A,)``, clipped to
  its bounds).
- ``env_driver`` (:class:`grt.policies.base.EnvDriverPolicy`: ``solve(env, seed)``, e.g. ManiSkill's
  motion-planning solutions): the session first resets the env with the trial's seed (that installs and
  settles the candidate, reconfiguring when the object changed), then calls
  ``policy.solve(env, seed=seed)`` with the session's gymnasium env wrapped by a step recorder. The policy
  may reset the env itself (``env.reset(seed=seed)``: the same episode, the candidate in place, because the
  swap and the settle live inside the env's own ``_load_scene`` / ``_initialize_episode``) and steps it as
  it likes. The trial is judged from the recorded steps as a closed-loop trial: success if the env reported
  success at any step, else the failure flags of the last step (the env's ``evaluate()`` now if it took no
  step); a failure no flag names is ``no_plan`` when the policy said it found no plan (``-1`` or
  ``{"planned": False}``), ``plan_ended`` when its plan ran to its end, and ``timeout`` only when it was
  stopped after ``driver_step_limit`` steps (20 x the env's ``max_episode_steps``: ManiSkill's solutions take
  more steps than the env's RL limit, so ``max_steps`` bounds closed-loop episodes only). The policy's last
  message (a failed plan's status) is the trial's ``note``.

**Object frames** are :mod:`grt.tasks.maniskill.geometry`'s: ``load_object`` takes GRT's frame (resting on
z = 0, centred in x/y) and converts to the actor frame by the stock actor's constant offset.
"""

from __future__ import annotations

import difflib
import functools
import gc
import importlib
import json
import logging
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import trimesh

from grt.config import at_least
from grt.tasks.base import COMMON_MODES, Episodes, TaskInputError
from grt.tasks.batched import EpisodeSession, Objects, info_at, to_numpy
from grt.tasks.maniskill.driver import StepLimit, StepRecorder
from grt.tasks.maniskill.geometry import ROUND_WEDGES, ActorFrame, check_grt_frame
from grt.tasks.maniskill.make import make_env
from grt.tasks.maniskill.swap import ActorSwap, Candidate

log = logging.getLogger(__name__)

RUNAWAY_M = 5.0  # an actor farther than this from the world origin was thrown out by the physics
#: how a trial of a policy that drives the env ends without success, when no failure flag names it: the
#: policy found no plan (it said so: ``-1`` or ``{"planned": False}``), or its plan ran to its end
DRIVER_MODES = ("no_plan", "plan_ended")


def failure_modes(flags) -> list[tuple[str, str]]:
    """``[(info flag, failure mode)]`` in order: a list derives each mode (``is_obj_placed`` -> ``not_placed``),
    a mapping gives them."""
    if isinstance(flags, Mapping):
        return [(str(k), str(v)) for k, v in flags.items()]
    if isinstance(flags, str):  # one flag's characters would be read as flags
        raise TaskInputError(f"task.session.failure_flags={flags}: give a list of the env's info flags "
                             f"(task.session.failure_flags=[{flags}]) or a mapping flag: mode")
    out = []
    for flag in flags or []:
        name = re.sub(r"^(is_|has_)", "", str(flag))
        name = re.sub(r"^(obj_|object_)", "", name)
        out.append((str(flag), f"not_{name}"))
    return out


def import_env_module(module: str | None) -> None:
    """Import the module that registers a user's env (``task.session.env_module``), in this process.

    Raises:
        TaskInputError: the module cannot be imported (names it and the error).
    """
    if not module:
        return
    try:
        importlib.import_module(str(module))
    except SystemExit as err:  # a module that exits on import would end the command without a word
        raise TaskInputError(f"task.session.env_module={module} called sys.exit({err.code!r}) while being imported; "
                             "it must be a module that registers the env when imported, without exiting") from None
    except Exception as err:  # noqa: BLE001 - any import failure is the same user problem
        raise TaskInputError(f"task.session.env_module={module} cannot be imported ({type(err).__name__}: {err}); it "
                             "must be an importable module (on PYTHONPATH or installed) that registers the env") from None


def check_env_id(env_id: str) -> None:
    """Refuse an env id ManiSkill has not registered, naming the close ones.

    Raises:
        TaskInputError: one line with the close registered names.
    """
    import difflib

    from mani_skill.utils.registration import REGISTERED_ENVS

    if env_id in REGISTERED_ENVS:
        return
    close = difflib.get_close_matches(env_id, list(REGISTERED_ENVS), n=5, cutoff=0.5)
    hint = f"close names: {', '.join(close)}" if close else f"{len(REGISTERED_ENVS)} are registered"
    raise TaskInputError(f"task.env_id={env_id} is not a registered ManiSkill env ({hint}); a user's own env: name "
                         "the module that registers it in task.session.env_module")


def _resolve(path: str | None):
    if not path:
        return None
    module, _, name = str(path).rpartition(".")
    try:
        found = getattr(importlib.import_module(module), name)
    except Exception as err:  # noqa: BLE001
        raise TaskInputError(f"task.session.refresh={path} cannot be imported ({type(err).__name__}: {err}); give a "
                             "function module.name(env, swap) -> {attribute: value}, or null") from None
    if not callable(found):
        raise TaskInputError(f"task.session.refresh={path} is not a function (it is {found!r}); give a "
                             "function module.name(env, swap) -> {attribute: value}, or null")
    return found


class ManiSkillSession(EpisodeSession):
    """Episodes of one policy on one registered ManiSkill env, one actor swapped for the candidate.

    Args:
        policy: a closed-loop :class:`~grt.policies.base.BatchedPolicy` or an env driver (``solve``);
            ``None`` in a learning worker.
        task_name: the task's name (``conf/task/<name>.yaml``), checked against a learned policy's.
        env_id: the registered env; env_kwargs: more ``gym.make`` arguments (``robot_uids``, ...).
        obs_mode, control_mode: ManiSkill's (``state``; ``pd_ee_delta_pos``, ...).
        actor: the actor to swap, exact builder name or a regex (``re.fullmatch``).
        score: ``success`` or an info key (a continuous score, per trial at its end).
        failure_flags: ordered info flags (list) or ``{flag: mode}``.
        refresh: dotted path of ``refresh(env, swap) -> {attribute: value}`` (the stale-nominal fix).
        env_module: a module imported first (it registers a user's env).
        max_steps: control steps per episode (``None``: the env's ``max_episode_steps``).
        rebuild_each_trial: reconfigure before every trial (see :class:`~grt.tasks.base.EpisodeSession`).
        driver_step_limit: steps an env-driving policy may take (``None``: 20 x ``max_steps``).
        num_envs, sim_backend, render_backend, sim_config: ManiSkill's (``evaluator=gpu`` sets them:
            :mod:`grt.tasks.batched`; more than one sub-scene for closed-loop policies only).
        round_wedges: surface caps added to a round actor's parts (:func:`~.geometry.round_wedges`; 0: none).
    """

    policy_kinds = ("closed_loop", "env_driver")
    #: preflight checks a policy without a `check` of its own on the env's sizes (grt.tasks.check_policy_io)
    probe_policies = True

    def __init__(self, policy=None, task_name: str = "", env_id: str = "PickCube-v1", env_kwargs: dict | None = None,
                 obs_mode: str = "state", control_mode: str | None = None, actor: str = "cube",
                 score: str = "success", score_unit: str = "", failure_flags=None, refresh: str | None = None,
                 env_module: str | None = None, max_steps: int | None = None, rebuild_each_trial: bool = False,
                 driver_step_limit: int | None = None, num_envs: int = 1, sim_backend: str = "physx_cpu",
                 render_backend: str = "cpu", sim_config: dict | None = None, round_wedges: int = ROUND_WEDGES):

        import_env_module(env_module)
        import mani_skill.envs  # noqa: F401 - registers the stock envs

        check_env_id(str(env_id))
        for key, value in (("max_steps", max_steps), ("driver_step_limit", driver_step_limit)):
            if value is not None and not at_least(1).check(value):
                raise TaskInputError(f"task.session.{key}={value}: give {at_least(1).accepts} (control steps), or null for "
                                     + ("the env's own max_episode_steps" if key == "max_steps" else "20 x max_steps"))
        if not at_least(0).check(round_wedges):
            raise TaskInputError(f"task.session.round_wedges={round_wedges}: give {at_least(0).accepts} (surface caps "
                                 "added to a round actor's convex parts; 0: none)")
        super().__init__(policy, 1, rebuild_each_trial)
        self.task_name, self.env_id, self.actor = str(task_name), str(env_id), str(actor)
        try:
            re.compile(self.actor)
        except re.error as err:
            raise TaskInputError(f"task.session.actor={actor!r} is no valid regex ({err}); give the actor's name") from None
        self.score_key, self.score_unit = str(score), str(score_unit or "")
        self.flags = failure_modes(failure_flags)
        self.failure_modes = (*COMMON_MODES, *(m for _, m in self.flags), "timeout", *DRIVER_MODES)
        self.swap = ActorSwap(self.actor, _resolve(refresh), int(round_wedges))
        self.num_envs = int(num_envs)
        kwargs = dict(obs_mode=obs_mode, sim_backend=sim_backend, render_backend=render_backend, num_envs=self.num_envs,
                      **({"sim_config": dict(sim_config)} if sim_config else {}), **(env_kwargs or {}))
        if control_mode:
            kwargs["control_mode"] = control_mode
        if max_steps:
            kwargs["max_episode_steps"] = int(max_steps)
        with self.swap.active():
            self.env = make_env(self.env_id, kwargs)  # a mistyped mode or robot: one line
        self.unwrapped = self.env.unwrapped
        try:
            self._check_actor()
        except TaskInputError:
            self.env.close()
            raise
        self.swap.attach(self.unwrapped)
        self.frame = ActorFrame.of(self.swap.reference)
        from mani_skill.utils.registration import REGISTERED_ENVS

        self.max_steps = int(max_steps or REGISTERED_ENVS[self.env_id].max_episode_steps or 100)
        self.driver_step_limit = int(driver_step_limit or 20 * self.max_steps)
        space = self.env.action_space
        self.action_low, self.action_high = np.asarray(space.low, np.float32), np.asarray(space.high, np.float32)
        self.num_actions = int(np.prod(space.shape))
        self._object_changed = False
        self._reset_batch([0] * self.num_envs, False)
        self.obs_spec = {k: tuple(v.shape) for k, v in self.observe().items()}
        self._check_info_keys()
        self._check_policy()
        gc.collect()

    # ------------------------------------------------------------------ set-up checks
    def _check_info_keys(self) -> None:
        """The score key and the failure flags are keys of the env's info (``get_info`` after the reset), or a
        one-line refusal naming the keys it has: found here, in the command's process before anything is
        written, not as a ``sim_error`` of every trial of a run whose saved config then holds the typo."""
        try:
            info = self.unwrapped.get_info()
        except Exception:  # noqa: BLE001 - an env that cannot evaluate before its first step: judged per trial
            return
        for key, where in [*((f, "task.session.failure_flags") for f, _ in self.flags),
                           *(() if self.score_key == "success" else ((self.score_key, "task.session.score"),))]:
            if key not in info:
                self.env.close()
                close = difflib.get_close_matches(key, list(info), n=1)
                hint = f"; did you mean {close[0]}?" if close else ""
                raise TaskInputError(f"{where}: {key!r} is not a key of {self.env_id}'s info; it has "
                                     f"{', '.join(sorted(info))}{hint}")

    def _check_actor(self) -> None:
        """Exactly one actor of the env matches ``actor`` (per sub-scene), or a one-line refusal."""
        builds = self.swap.builds
        per_scene = {}  # sub-scene -> the matching actors built in it (peg_0, peg_1, ... on a GPU: one each)
        for b in builds:
            for i in b.scene_idxs:
                per_scene.setdefault(i, []).append(b.name)
        several = next((names for names in per_scene.values() if len(names) > 1), None)
        if several:
            raise TaskInputError(f"task.session.actor={self.actor} matches {len(several)} actors of {self.env_id} "
                                 f"({', '.join(several)}): name one of them exactly")
        if builds:
            return
        for art_name, art in self.unwrapped.scene.articulations.items():
            links = [link.name for link in art.get_links()]
            hit = [n for n in [art_name, *links] if re.fullmatch(self.actor, n)]
            if hit:
                raise TaskInputError(f"task.session.actor={self.actor} is {'the articulation' if hit[0] == art_name else 'a link of the articulation'} "
                                     f"{art_name!r} of {self.env_id}: articulation links are not supported yet; swap one "
                                     f"of its actors: {', '.join(self.swap.names)}")
        raise TaskInputError(f"task.session.actor={self.actor} matches no actor of {self.env_id}; its actors: "
                             f"{', '.join(self.swap.names)}")

    @classmethod
    def check_object(cls, mesh: trimesh.Trimesh, **_) -> None:
        """The object must be in GRT's frame (see :func:`grt.tasks.maniskill.geometry.check_grt_frame`)."""
        check_grt_frame(mesh)

    @classmethod
    def observation_spec(cls, **session_kwargs) -> dict[str, tuple[int, ...]]:
        return dict(probe(session_kwargs).obs_spec)

    @classmethod
    def action_size(cls, **session_kwargs) -> int:
        return probe(session_kwargs).num_actions

    @classmethod
    def nominal_object(cls, **session_kwargs) -> trimesh.Trimesh:
        """The stock actor's geometry as one watertight mesh in GRT's frame (meters)."""
        return probe(session_kwargs).nominal.copy()

    # ------------------------------------------------------------------ objects
    def load_objects(self, objects: Objects, assignment) -> None:
        """Sub-scene ``i`` holds ``objects[assignment[i]]``: a candidate in GRT's frame (meters) and its convex
        parts, or ``(None, None)``: the stock actor (calibration, the swap check)."""
        cands = []
        for mesh, parts in objects:
            if mesh is None:
                cands.append(None)
                continue
            if not parts:
                raise ValueError("a candidate needs at least one convex collision part")
            actor_mesh = mesh.copy()
            actor_mesh.vertices = self.frame.to_actor(mesh.vertices)
            cands.append(Candidate(actor_mesh, [self.frame.to_actor(p) for p in parts]))
        self.swap.set_candidates({i: cands[int(a)] for i, a in enumerate(assignment)})
        self._object_changed = True

    # ------------------------------------------------------------------ EpisodeSession hooks
    def _step_batch(self, actions: np.ndarray):
        self._obs, reward, _, _, info = self.env.step(actions)
        out = self.info_batch(info)
        return to_numpy(reward).reshape(self.num_envs), out["success"].astype(bool), out

    def clip_actions(self, actions: np.ndarray) -> np.ndarray:
        return np.clip(actions, self.action_low, self.action_high)

    def check_batch(self, info: dict[str, np.ndarray]) -> list[str | None]:
        """A non-finite state (:meth:`EpisodeSession.check_batch`), then the swapped actor non-finite or run away,
        per sub-scene."""
        errors = super().check_batch(info)
        for b in self.swap.builds:
            p = to_numpy(b.actor.pose.p).astype(np.float64).reshape(-1, 3)
            far = np.linalg.norm(p, axis=-1)
            scenes = b.scene_idxs if len(b.scene_idxs) == len(p) else range(len(p))
            for k, i in enumerate(scenes):
                if errors[i] is None and not np.isfinite(p[k]).all():
                    errors[i] = f"FloatingPointError: the actor {b.name!r} has a non-finite pose"
                elif errors[i] is None and far[k] > RUNAWAY_M:
                    errors[i] = f"RuntimeError: the actor {b.name!r} ran away ({far[k]:.1f} m from the origin)"
        return errors

    def observe_batch(self) -> dict[str, np.ndarray]:
        """The env's last observation (of the last reset or step) as groups ``{name: (num_envs, ...)}``."""
        return {k: to_numpy(v).astype(np.float32) for k, v in _leaves(self._obs)}

    def _judge_driven(self, success: bool, info: dict, said, stopped: bool) -> str:
        """The mode of a driven trial: as :meth:`judge` (success, then the first failing flag), but a failure no
        flag names is ``timeout`` only when the policy was stopped at ``driver_step_limit``; else ``no_plan``
        when it said it found none, ``plan_ended`` when its plan ran to its end without success."""
        mode = self.judge(success, info)
        if mode != "timeout" or stopped:
            return mode
        planned = not (said == -1 or (isinstance(said, Mapping) and said.get("planned") is False))
        return "plan_ended" if planned else "no_plan"

    def judge(self, success: bool, info: dict) -> str:
        if success:
            return "success"
        for flag, mode in self.flags:
            if flag in info and not info[flag]:
                return mode
        return "timeout"

    def score(self, success: bool, info: dict) -> float:
        if self.score_key == "success":
            return float(success)
        return float(info[self.score_key])

    def info_batch(self, info: dict) -> dict[str, np.ndarray]:
        """What the judge reads of the env's info, batched: ``{key: (num_envs,)}`` for success, the failure
        flags and the score key (bool or float arrays).

        Raises:
            KeyError: a key the env's info does not have (names the keys it has).
        """
        keys = ["success", *(f for f, _ in self.flags)]
        if self.score_key != "success":
            keys.append(self.score_key)
        out = {}
        for key in dict.fromkeys(keys):
            if key not in info:
                raise KeyError(f"the env's info has no {key!r} (task.session.failure_flags / task.session.score); it has "
                               f"{', '.join(sorted(info))}")
            out[key] = to_numpy(info[key]).reshape(self.unwrapped.num_envs, -1)[:, 0]
        return out

    # ------------------------------------------------------------------ evaluation
    def _play(self, episodes: Episodes) -> None:
        if callable(getattr(self.policy, "solve", None)):
            self._drive(episodes)
        else:
            super()._play(episodes)

    def _drive(self, episodes: Episodes) -> None:
        """One episode of a policy that drives the env itself (see the module docstring)."""
        if self.num_envs != 1:
            raise ValueError(f"an env-driving policy runs one sub-scene per env, this session has {self.num_envs}")
        seed = episodes.seeds[0]
        self._reset_batch([seed], self.rebuild_each_trial)
        recorder = StepRecorder(self.env, self, self.driver_step_limit)
        said, stopped = None, False
        try:
            try:
                said = self.policy.solve(recorder, seed=seed)
            except StepLimit:
                stopped = True
        finally:
            episodes.steps[0] = self.steps = recorder.steps
        if recorder.error is not None:
            episodes.fail(0, recorder.error)
            return
        state = recorder.last or info_at(self.info_batch(self.unwrapped.get_info()), 0)
        success = recorder.success or bool(state["success"])
        episodes.end(0, self._judge_driven(success, state, said, stopped), self.score(success, state),
                     {**state, **driver_note(said, stopped, self.driver_step_limit)})


def driver_note(said, stopped: bool, limit: int) -> dict:
    """What a driven trial keeps of what its policy said: ``{"note": ...}`` (the planner's last message when
    it is not ``ok``, or the step limit it was stopped at), else ``{}``."""
    if stopped:
        return {"note": f"stopped after driver_step_limit={limit} steps"}
    status = str(said.get("status", "")) if isinstance(said, Mapping) else ("no plan" if said == -1 else "")
    return {"note": status[:300]} if status and status != "ok" else {}


def _leaves(obs, prefix: str = ""):
    """``(group, tensor)`` of an observation: a tensor is ``state``; a dict gives one group per leaf."""
    if not isinstance(obs, Mapping):
        yield (prefix or "state"), obs
        return
    for key, value in obs.items():
        yield from _leaves(value, f"{prefix}/{key}" if prefix else str(key))


# ------------------------------------------------------------------ the env, probed in the command's process
@dataclass(frozen=True)
class Probe:
    """A task env's sizes and stock actor.

    Attributes:
        obs_spec: observation groups ``{name: shape}``; num_actions: the action size.
        nominal: the stock actor's geometry in GRT's frame (m); offset: the actor frame's offset (m).
        actors: every actor name of the env; max_steps: control steps per episode.
        mass: the stock actor's mass (kg); extents: its collision geometry's extents in the actor frame (m).
    """

    obs_spec: dict
    num_actions: int
    nominal: trimesh.Trimesh
    offset: tuple
    actors: tuple
    max_steps: int
    mass: float
    extents: tuple


def probe(session_kwargs: Mapping) -> Probe:
    """The :class:`Probe` of a ManiSkill task's ``session`` config (``_target_`` and ``policy`` ignored)."""
    kwargs = {k: v for k, v in dict(session_kwargs).items() if k not in ("_target_", "policy")}
    return _probe(json.dumps(kwargs, sort_keys=True, default=str))


@functools.lru_cache(maxsize=8)
def _probe(key: str) -> Probe:
    session = ManiSkillSession(policy=None, **json.loads(key))
    try:
        build = session.swap.build_of(0)
        mass = float(np.sum([_mass(build.actor)]))
        return Probe(dict(session.obs_spec), session.num_actions, session.frame.mesh_to_grt(session.swap.reference),
                     tuple(session.frame.offset.tolist()), tuple(session.swap.names), session.max_steps, mass,
                     tuple(np.asarray(build.stock.extents).tolist()))
    finally:
        session.close()


def _mass(actor) -> float:
    """The mass (kg) of a ManiSkill actor's first body."""
    from sapien import physx

    body = actor._objs[0].find_component_by_type(physx.PhysxRigidDynamicComponent)
    return float(body.mass) if body is not None else float("nan")
