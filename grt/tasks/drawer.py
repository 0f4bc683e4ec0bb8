"""The drawer task session: one GRT-Drawer-v1 env, seeded drawer-opening episodes, learning and evaluation.

An episode (paper appendix, articulated manipulation): the drawer starts closed and the robot near its
rest pose (±0.25 rad per joint); the policy commands joint deltas until the drawer is fully open
(``success_opening``, 0.38 m of 0.39 m) or 500 control steps have passed. The trial's **score is the final
opening in meters** (continuous): a red team sees graded failure. Every trial is also named:

- ``success``: the drawer is fully open;
- ``slipped``: the fingers held the handle at some point, then lost it, the drawer not fully open;
- ``partial_open``: the drawer moved (> 2 cm) or is still held, but did not open fully in time;
- ``missed_handle``: the TCP came to the grasp point (< 3 cm) but the fingers never held the handle;
- ``timeout``: the policy never reached the handle;
- ``sim_error``: a physics failure (non-finite state).

The grasp point the policy observes is the *nominal* handle's (``handle_object``); a deformed handle
is attached at the same mounting frame, so the policy does not see the deformation.
"""

from __future__ import annotations

import numpy as np
import trimesh

from grt.policies.drawer_action import GRASP_ROT
from grt.tasks.base import COMMON_MODES, TaskInputError
from grt.tasks.batched import EpisodeSession, to_numpy
from grt.tasks.drawer_env import HANDLE_ROT, MAX_OPENING, STATE_DIM, CabinetSpec, DrawerEnv

__all__ = ["DrawerEnv", "DrawerSession", "HandleFitError", "handle_grasp_point"]

MAX_GRIP = 0.07  # m: what the Panda's fingers (0.08 m) can close around, with a margin


class HandleFitError(TaskInputError):
    """A handle the drawer task cannot use (a user error: the message names the fix)."""


def handle_grasp_point(spec: str, grasp_point=None) -> np.ndarray:
    """The grasp point (m, handle frame) of a handle: the given one, else the built-in handle's.

    Raises:
        HandleFitError: a user's handle file without ``grasp_point``.
    """
    from grt.objects import BUILDERS, object_info

    if grasp_point is not None:
        point = np.asarray(list(grasp_point), np.float64)
        if point.shape != (3,) or not np.all(np.isfinite(point)):
            raise HandleFitError(f"task.session.grasp_point must be three numbers in meters, got {grasp_point!r}")
        return point
    known = object_info(spec).get("drawer") if spec in BUILDERS else None
    if known is None:
        raise HandleFitError(f"{spec!r} is no built-in drawer handle: give the point the gripper should pinch, in the "
                             "handle's frame (m; z = 0 is the mounting plane on the drawer front), e.g. "
                             "task.session.grasp_point=[0,0,0.032]")
    return np.asarray(known["grasp"], np.float64)


def check_handle(mesh: trimesh.Trimesh, grasp_point: np.ndarray, cabinet: CabinetSpec, what: str = "the handle") -> None:
    """Refuse a handle that does not fit the drawer front, reaches into the drawer, or cannot be grasped.

    Raises:
        HandleFitError: naming the problem and the fix.
    """
    v = np.asarray(mesh.vertices, np.float64)
    lo, hi = v.min(0), v.max(0)
    width, height = cabinet.front_size[0], cabinet.front_size[1]
    if lo[2] < -0.002:
        raise HandleFitError(f"{what} reaches {-lo[2] * 1000:.0f} mm behind its mounting plane into the drawer front: "
                             "in the handle frame z = 0 is the front and the handle stands on it (z >= 0); "
                             "check the mesh's orientation and units")
    if lo[2] > 0.002:
        raise HandleFitError(f"{what} floats {lo[2] * 1000:.0f} mm in front of its mounting plane: in the handle frame "
                             "z = 0 is the drawer front and the handle's feet stand on it; move the mesh down by "
                             f"{lo[2] * 1000:.1f} mm in a modelling tool (trimesh: mesh.apply_translation([0, 0, "
                             f"{-lo[2]:.4f}])) and export it again")
    if max(abs(lo[0]), abs(hi[0])) > width / 2 or max(abs(lo[1]), abs(hi[1])) > height / 2:
        raise HandleFitError(f"{what} ({(hi[0] - lo[0]) * 1000:.0f} x {(hi[1] - lo[1]) * 1000:.0f} mm across the front) "
                             f"does not fit the drawer front ({width * 1000:.0f} x {height * 1000:.0f} mm, centered): "
                             "use a smaller handle, or check its units (meters) and centering")
    if hi[2] > 0.15:
        raise HandleFitError(f"{what} sticks out {hi[2] * 1000:.0f} mm from the drawer front (at most 150 mm): "
                             "check its units (meters) and that z points out of the front")
    # Across the fingers at the grasp point: the closing direction in the handle frame.
    closing = HANDLE_ROT.T @ GRASP_ROT[:, 1]
    near = v[np.abs(v[:, 0] - grasp_point[0]) < 0.005]
    if len(near) == 0:
        raise HandleFitError(f"{what} has no surface within 5 mm of the grasp point's x = {grasp_point[0]:.3f} m: "
                             "set task.session.grasp_point on the handle's grip")
    span = np.ptp(near @ closing)
    if span > MAX_GRIP:
        raise HandleFitError(f"{what} is {span * 1000:.0f} mm thick across the fingers at the grasp point; the Panda "
                             f"closes around at most {MAX_GRIP * 1000:.0f} mm: use a thinner grip, or check its units")


class DrawerSession(EpisodeSession):
    """Drawer-opening episodes of one policy on one handle at a time, or on ``num_envs`` sub-scenes at once.

    Args:
        policy: a :class:`grt.policies.base.BatchedPolicy` (``None`` for a learning worker).
        handle_object: the nominal handle (built-in name or mesh path): its grasp point is observed.
        grasp_point: the nominal grasp point (m, handle frame); ``None``: the built-in handle's.
        max_steps: control steps per episode (paper: 500).
        cabinet: :class:`grt.tasks.drawer_env.CabinetSpec` fields to override.
        env_id, env: the registered ManiSkill env and further :class:`DrawerEnv` arguments.
        rebuild_each_trial, num_envs, sim_backend, render_backend, sim_config: see
            :class:`grt.tasks.batched.EpisodeSession`.
    """

    task_name, score_name = "drawer", "opening"
    obs_spec, num_actions = {"state": (STATE_DIM,)}, 9
    failure_modes = (*COMMON_MODES, "missed_handle", "slipped", "partial_open", "timeout")
    # worst cases measured at a load average of 13 on 2 cores (scripts/step_times.py, drawer_state): a control
    # step 15.7 ms on average (4.4 ms at load 11), a reset at most 0.47 s; rounded up
    STEP_S, RESET_S = 0.02, 0.5

    def __init__(self, policy=None, handle_object: str = "drawer_handle", grasp_point=None, max_steps: int = 500,
                 cabinet: dict | None = None, env_id: str = "GRT-Drawer-v1", env: dict | None = None,
                 rebuild_each_trial: bool = True, num_envs: int = 1, sim_backend: str = "physx_cpu",
                 render_backend: str = "cpu", sim_config: dict | None = None):
        super().__init__(policy, max_steps, rebuild_each_trial)
        from grt.geometry.mesh import load_mesh

        self.grasp_point = handle_grasp_point(str(handle_object), grasp_point)
        self.cabinet = CabinetSpec(**(cabinet or {}))
        check_handle(load_mesh(handle_object), self.grasp_point, self.cabinet, "the nominal handle")
        self.obs_spec = self.observation_spec()
        self._check_policy()
        self._make_env(env_id, num_envs, sim_backend, render_backend, sim_config,
                       grasp_point=tuple(self.grasp_point), cabinet=dict(cabinet or {}), **(env or {}))

    @classmethod
    def check_object(cls, mesh: trimesh.Trimesh, handle_object: str = "drawer_handle", grasp_point=None,
                     cabinet: dict | None = None, **_) -> None:
        """The handle must fit the drawer front and the gripper (see :class:`HandleFitError`)."""
        from grt.geometry.mesh import load_mesh

        point = handle_grasp_point(str(handle_object), grasp_point)
        spec = CabinetSpec(**(cabinet or {}))
        check_handle(load_mesh(handle_object), point, spec, "the nominal handle")
        check_handle(mesh, point, spec)

    # --- EpisodeSession hooks ------------------------------------------------------------------------
    def _reset_batch(self, seeds, rebuild: bool) -> None:
        super()._reset_batch(seeds, rebuild)
        self._held = np.zeros(self.num_envs, bool)
        self._reached = np.zeros(self.num_envs, bool)

    def _step_batch(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        _, reward, _, _, info = self.env.step(actions)
        state = {k: to_numpy(info[k]).astype(np.float64) for k in ("opening", "drawer_vel", "tcp_to_grasp",
                                                                   "finger_width")}
        state["holding"] = to_numpy(info["holding"]).astype(bool)
        self._held = self._held | state["holding"]
        self._reached = self._reached | (state["tcp_to_grasp"] < 0.03)
        state.update(ever_held=self._held.copy(), reached=self._reached.copy())
        return to_numpy(reward), to_numpy(info["success"]).astype(bool), state

    def score(self, success: bool, info: dict) -> float:
        return float(info["opening"])

    def judge(self, success: bool, info: dict) -> str:
        if success:
            return "success"
        if info["ever_held"] and not info["holding"]:
            return "slipped"
        if info["holding"] or info["opening"] > 0.02:
            return "partial_open"
        if info["reached"]:
            return "missed_handle"
        return "timeout"

    def check_batch(self, info: dict[str, np.ndarray]) -> list[str | None]:
        errors = super().check_batch(info)
        opening = info["opening"]
        for i in np.flatnonzero((opening < -0.01) | (opening > MAX_OPENING + 0.01)):
            if errors[i] is None:
                errors[i] = f"RuntimeError: the drawer left its slide (opening {opening[i]:.3f} m)"
        return errors
