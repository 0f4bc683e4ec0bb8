"""The insertion task session: one GRT-Insert-v1 env, seeded insertion episodes, learning and evaluation.

An episode (paper appendix "High-Precision Insertion Task"): the socket is placed at random, the plug
starts pinched above it, and the policy moves the hand with 6-D delta poses until the plug's tip is
within 3 mm of the hole's floor (success) or 256 control steps have passed. A failed trial is named:

- ``dropped``: the plug left the fingers (its grip point is > 15 mm from the TCP, or no finger holds it);
- ``jammed``: the plug's tip is in the hole's mouth (within 2 mm of its axis) but did not go down;
- ``misaligned``: the plug turned in the hand (> 10 deg tilt) or its tip ended off the hole's axis
  after touching the socket;
- ``timeout``: none of the above: the policy never brought the plug to the socket;
- ``sim_error``: a physics failure (non-finite state, runaway plug).

The socket is built once per session from the *nominal* plug (``socket_object``), so a CrashShape
goes into the same socket as the nominal plug.
"""

from __future__ import annotations

import numpy as np
import trimesh

from grt.tasks.base import COMMON_MODES
from grt.tasks.batched import EpisodeSession, Objects, to_numpy
from grt.tasks.insertion_env import GRIP_DIM, STATE_DIM, InsertEnv  # registers GRT-Insert-v1
from grt.tasks.socket import PlugFitError, build_socket, grip_half_width

__all__ = ["InsertEnv", "InsertionSession", "PlugFitError", "check_tip", "plug_geometry"]

MAX_GRIPPER_WIDTH = 0.08  # m: the Panda's fingers open 2 x 0.04
GRIP_CLEARANCE = 0.004  # m kept free between the open fingers and the plug: the widest grip is 76 mm
TIP_TOLERANCE = 0.0001  # m: how far from z = 0 a plug's tip may be


def plug_geometry(spec: str, head_length: float | None, grip_height: float | None) -> tuple[float, float]:
    """``(head_length, grip_height)`` (m) of a plug: given values, else the built-in object's.

    Raises:
        PlugFitError: a user's plug file without ``head_length`` / ``grip_height``.
    """
    from grt.objects import BUILDERS, INSERTION, object_info

    if head_length is not None and grip_height is not None:
        return float(head_length), float(grip_height)
    known = object_info(spec).get("insertion") if spec in BUILDERS else None
    given = ("give its connector length and grip height, e.g. task.session.head_length=0.012 "
             "task.session.grip_height=0.03 (meters, tip at z = 0)")
    if known is None and spec in BUILDERS:  # e.g. 'plug': lies on its side, a grasp object
        info = object_info(spec)
        raise PlugFitError(f"{spec!r} is a built-in object of the {info['task']} task ({info['description']}), not an "
                           f"insertion plug: the insertion task's built-in plugs are {', '.join(sorted(INSERTION))} "
                           f"(object={sorted(INSERTION)[-1]}); for a plug of your own, {given}")
    if known is None:
        raise PlugFitError(f"{spec!r} is no built-in plug: {given}")
    return (float(head_length if head_length is not None else known["head_length"]),
            float(grip_height if grip_height is not None else known["grip_height"]))


def _check_grip(mesh: trimesh.Trimesh, grip_height: float) -> None:
    """The plug has a surface at the grip height, narrow enough for the Panda's fingers."""
    width = 2 * grip_half_width(mesh, grip_height)
    widest = MAX_GRIPPER_WIDTH - GRIP_CLEARANCE
    if width > widest:
        raise PlugFitError(f"the plug's grip is {width * 1000:.0f} mm wide across the fingers; the widest grip the "
                           f"task accepts is {widest * 1000:.0f} mm (the Panda opens {MAX_GRIPPER_WIDTH * 1000:.0f} mm, "
                           f"{GRIP_CLEARANCE * 1000:.0f} mm kept for clearance): use a narrower plug, or check its units")


def check_tip(mesh: trimesh.Trimesh, what: str = "the plug") -> None:
    """A plug's tip is at z = 0 with its connector pointing down (-z): GRT's convention, which the socket,
    ``head_length`` and ``grip_height`` are measured from.

    Raises:
        PlugFitError: the lowest point is not at z = 0 (the message gives the shift that fixes it).
    """
    tip = float(np.asarray(mesh.vertices)[:, 2].min())
    if abs(tip) > TIP_TOLERANCE:
        raise PlugFitError(f"{what}'s tip is at z = {tip * 1000:.1f} mm; GRT's plugs have their tip at z = 0 with the "
                           f"connector pointing down (head_length and grip_height are measured from it): move the mesh "
                           f"{'up' if tip < 0 else 'down'} by {abs(tip) * 1000:.1f} mm in a modelling tool (trimesh: "
                           f"mesh.apply_translation([0, 0, {-tip:.4f}])) and export it again")


class InsertionSession(EpisodeSession):
    """Insertion episodes of one policy on one plug at a time, or on ``num_envs`` sub-scenes at once.

    Args:
        policy: a :class:`grt.policies.base.BatchedPolicy` (``None`` for a learning worker).
        socket_object: the nominal plug (built-in name or mesh path) the socket is made for.
        head_length, grip_height: the plug's connector length and grip point (m); ``None``: the
            built-in plug's values.
        clearance, chamfer: the socket's hole (m per side) and entrance chamfer (m).
        max_steps: control steps per episode (paper: 256).
        cloud_points: points in the ``cloud`` observation (paper: 500; 0 for state-only policies).
        env_id, env: the registered ManiSkill env and further :class:`InsertEnv` arguments.
        rebuild_each_trial, num_envs, sim_backend, render_backend, sim_config: see
            :class:`grt.tasks.batched.EpisodeSession`.
    """

    num_actions = 6
    task_name = "insertion"
    failure_modes = (*COMMON_MODES, "jammed", "misaligned", "dropped", "timeout")
    # worst cases measured at a load average of 11 on 2 cores (scripts/step_times.py): a control step of the
    # slowest shipped policy, insertion_pcd, 127 ms on average (its act 95 ms; insertion_state's step: 24 ms), a
    # reset at most 0.48 s; rounded up
    STEP_S, RESET_S = 0.15, 0.5

    def __init__(self, policy=None, socket_object: str = "usb_plug", head_length: float | None = None,
                 grip_height: float | None = None, clearance: float = 0.0004, chamfer: float = 0.0015,
                 max_steps: int = 256, cloud_points: int = 500, env_id: str = "GRT-Insert-v1",
                 env: dict | None = None, rebuild_each_trial: bool = True, num_envs: int = 1,
                 sim_backend: str = "physx_cpu", render_backend: str = "cpu", sim_config: dict | None = None):
        super().__init__(policy, max_steps, rebuild_each_trial)
        from grt.geometry.mesh import load_mesh

        self.head_length, self.grip_height = plug_geometry(str(socket_object), head_length, grip_height)
        nominal = load_mesh(socket_object)
        check_tip(nominal, "the nominal plug")
        _check_grip(nominal, self.grip_height)
        self.socket = build_socket(nominal, self.head_length, clearance=clearance, chamfer=chamfer)
        self.obs_spec = self.observation_spec(cloud_points=cloud_points)
        self._check_policy()
        self._make_env(env_id, num_envs, sim_backend, render_backend, sim_config, head_length=self.head_length,
                       grip_height=self.grip_height, cloud_points=int(cloud_points), plug=nominal, **(env or {}))
        self.unwrapped.set_socket(self.socket)

    @classmethod
    def observation_spec(cls, cloud_points: int = 500, **_) -> dict[str, tuple[int, ...]]:
        spec = {"state": (STATE_DIM,), "grip": (GRIP_DIM,)}
        if cloud_points:
            spec["cloud"] = (int(cloud_points), 3)
        return spec

    @classmethod
    def check_object(cls, mesh: trimesh.Trimesh, socket_object: str = "usb_plug", head_length: float | None = None,
                     grip_height: float | None = None, clearance: float = 0.0004, **_) -> None:
        """The plug must fit the gripper and have a head to build the socket from (see :class:`PlugFitError`)."""
        from grt.geometry.mesh import load_mesh

        head, grip = plug_geometry(str(socket_object), head_length, grip_height)
        check_tip(mesh)
        _check_grip(mesh, grip)
        nominal = load_mesh(socket_object)
        check_tip(nominal, "the nominal plug (task.session.socket_object)")
        _check_grip(nominal, grip)
        socket = build_socket(nominal, head, clearance=clearance)
        if socket.outer_radius > 0.1:
            raise PlugFitError(f"the plug's head is {2 * socket.outer_radius * 1000:.0f} mm across: too big for a "
                               "tabletop socket; is the mesh in meters (object_scale) and head_length right?")

    @classmethod
    def check_candidate(cls, mesh: trimesh.Trimesh, socket_object: str = "usb_plug", head_length: float | None = None,
                        grip_height: float | None = None, **_) -> None:
        """The check :meth:`load_objects` makes: the plug's grip fits the gripper."""
        _check_grip(mesh, plug_geometry(str(socket_object), head_length, grip_height)[1])

    def load_objects(self, objects: Objects, assignment) -> None:
        for mesh, _ in objects:
            _check_grip(mesh, self.grip_height)
        super().load_objects(objects, assignment)

    # --- EpisodeSession hooks ------------------------------------------------------------------------
    def _reset_batch(self, seeds, rebuild: bool) -> None:
        super()._reset_batch(seeds, rebuild)
        self._touched = np.zeros(self.num_envs, bool)

    def start_errors(self) -> list[str | None]:
        return list(self.unwrapped.start_errors)

    def _step_batch(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        _, reward, _, _, info = self.env.step(actions)
        state = {k: to_numpy(info[k]).astype(np.float64) for k in ("tip_to_floor", "tip_off_axis", "keypoint_error",
                                                                   "grip_offset", "tilt_deg")}
        state["pinched"] = to_numpy(info["pinched"]).astype(bool)
        self._touched = self._touched | ((state["tip_to_floor"] < self.socket.depth + 0.002)
                                         & (state["tip_off_axis"] < 0.01))
        state["touched_socket"] = self._touched.copy()
        return to_numpy(reward), to_numpy(info["success"]).astype(bool), state

    def judge(self, success: bool, info: dict) -> str:
        if success:
            return "success"
        if info["grip_offset"] > 0.015 or not info["pinched"]:
            return "dropped"
        if info["tip_off_axis"] < 0.002 and info["tip_to_floor"] < self.socket.depth + 0.002:
            return "jammed"
        if info["tilt_deg"] > 10.0 or info["touched_socket"]:
            return "misaligned"
        return "timeout"

    def hopeless_batch(self, info: dict[str, np.ndarray]) -> np.ndarray:
        return info["grip_offset"] > 0.015  # the plug left the fingers: it cannot be inserted any more

    def check_batch(self, info: dict[str, np.ndarray]) -> list[str | None]:
        errors = super().check_batch(info)
        for i in np.flatnonzero(info["grip_offset"] > 0.5):
            if errors[i] is None:
                errors[i] = f"RuntimeError: the plug ran away ({info['grip_offset'][i]:.2f} m from the hand)"
        return errors
