"""GRT-Drawer-v1: a Panda opens a cabinet drawer by its handle (the paper's articulated domain).

**Description.** A procedural cabinet (:func:`build_cabinet`: a fixed body of boxes and one drawer on a
prismatic joint, maximum opening 0.39 m, with joint friction and damping so that opening it takes a
real pull) stands on the floor in front of a Franka Panda (base at the origin, the drawer front facing
it at ``x = front_x``). The drawer carries the handle, the deformable object, built from the candidate's
convex parts. The policy commands 9-D joint deltas in [-1, 1]: the 7 arm joints and the 2 fingers each,
scaled by ``ARM_DELTA`` rad and ``FINGER_DELTA`` m per control step: PD position targets set to the
current joint positions plus the delta (ManiSkill's ``pd_joint_delta_pos``), clipped to the joint
limits. The paper (Isaac Gym) accumulates ``target += dt * 7.5 * action`` at 60 Hz; accumulated targets
wind up under contact (a held "close" grows without bound, a servo overshoots), so GRT uses ManiSkill's
delta-from-current controller at the same 60 Hz, 0.05 rad (3 rad/s) per step at ``|a| = 1``.

**Observations** (:meth:`DrawerEnv.task_obs`), ``state`` (23,) as the paper's: 9 joint positions, 9 joint
velocities x 0.1, the 3-D vector from the TCP to the handle's grasp point, the drawer's opening (m) and
its velocity (m/s). The grasp point is the *nominal* handle's (fixed on the drawer, moving with it): a
policy does not see the deformed handle.

**Randomizations** (per seeded reset). The drawer starts closed; the robot's 7 arm joints start at a
rest pose plus uniform ±0.25 rad noise (paper), fingers open.

**Success.** The drawer is open at least ``success_opening`` (0.38 m of 0.39 m): the episode ends there
(the opening cannot grow further). The trial's score is the final opening in meters (continuous).

**Deformable object.** The handle: visual = the candidate mesh, collision = its convex parts, from
memory, attached to the drawer link with the mounting plane (handle frame ``z = 0``) on the drawer
front, the handle's ``x`` along the drawer's width and its ``y`` vertical. Swap it with
:meth:`DrawerEnv.set_object` then ``reset(options={"reconfigure": True})``.

**Parallel sub-scenes** (``num_envs > 1``, ``physx_cuda``). Sub-scene ``i``'s cabinet carries its own handle
(:meth:`DrawerEnv.set_objects`: one articulation per sub-scene, then ``Articulation.merge``) and runs the
episode of its own seed, drawn as with one env; states and observations are ``(num_envs, ...)`` arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien
import torch
import trimesh
from mani_skill.agents.controllers import PDJointPosControllerConfig
from mani_skill.agents.controllers.pd_joint_pos import PDJointPosController
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots import Panda
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.building.ground import build_ground
from mani_skill.utils.registration import register_env
from mani_skill.utils.structs.articulation import Articulation
from sapien import physx

from grt.policies.drawer_action import APPROACH, ARM_DELTA, FINGER_DELTA, GRASP_ROT
from grt.tasks.batched import to_numpy
from grt.tasks.env_base import TaskEnv
from grt.tasks.scene import CPU_INFLATION, GPU_INFLATION, attach_convex_parts, new_tally, render_mesh_shape

STATE_DIM = 23
MAX_OPENING = 0.39    # m (paper)
# The handle frame in the drawer frame: handle x -> world -y, handle y -> world z, handle z -> world -x.
HANDLE_ROT = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

class _ClippedController(PDJointPosController):
    """Joint-delta targets (from the current joint positions) clipped to the joint limits."""

    def set_action(self, action):
        super().set_action(action)
        limits = self.articulation.get_qlimits()[..., self.active_joint_indices, :]
        lo, hi = limits[..., 0].to(self._target_qpos.dtype), limits[..., 1].to(self._target_qpos.dtype)
        self._target_qpos = torch.maximum(torch.minimum(self._target_qpos, hi), lo)
        self.set_drive_targets(self._target_qpos)


@dataclass
class _ClippedConfig(PDJointPosControllerConfig):
    controller_cls = _ClippedController


@register_agent(override=True)  # by uid, so the env's SUPPORTED_ROBOTS check knows it
class PandaDrawer(Panda):
    """The Panda with the paper's drawer action: 9 joint deltas (7 arm joints, 2 independent fingers)."""

    uid = "panda_drawer"

    @property
    def _controller_configs(self):
        arm = _ClippedConfig(self.arm_joint_names, -ARM_DELTA, ARM_DELTA, self.arm_stiffness, self.arm_damping,
                             self.arm_force_limit, use_delta=True)
        fingers = _ClippedConfig(self.gripper_joint_names, -FINGER_DELTA, FINGER_DELTA, self.gripper_stiffness,
                                 self.gripper_damping, self.gripper_force_limit, use_delta=True)
        return dict(pd_joint_delta_pos=dict(arm=arm, gripper=fingers))


@dataclass
class CabinetSpec:
    """The procedural cabinet (meters). The drawer front's outer face is the plane ``x = front_x`` when
    closed; its center is at height ``drawer_z``.

    Attributes:
        front_x: x of the closed drawer front's outer face.
        drawer_z: height of the drawer front's center.
        front_size: (width along y, height along z, thickness along x) of the drawer front.
        depth: drawer box depth along x (longer than the opening so the drawer stays supported).
        body_width, body_height: the cabinet body's outer width (y) and height (z, from the floor).
        friction: the drawer joint's friction coefficient (PhysX: times the joint's constraint force,
            about the drawer's ~12 N weight); damping: its viscous damping (N s/m).
    """

    front_x: float = 0.78
    drawer_z: float = 0.65
    front_size: tuple[float, float, float] = (0.36, 0.16, 0.02)
    depth: float = 0.42
    body_width: float = 0.42
    body_height: float = 0.76
    friction: float = 0.3
    damping: float = 10.0

    def handle_pose(self) -> np.ndarray:
        """``(4, 4)`` pose of the handle frame in the drawer link frame (= the world at opening 0)."""
        out = np.eye(4)
        out[:3, :3] = HANDLE_ROT
        out[:3, 3] = [self.front_x, 0.0, self.drawer_z]
        return out


def default_handle() -> tuple[trimesh.Trimesh, list[np.ndarray]]:
    """The built-in bar handle and three convex parts (grip, feet): the handle before any ``set_object``."""
    from grt.objects import get_object, object_regions

    mesh = get_object("drawer_handle")
    v = np.asarray(mesh.vertices)
    boxes = object_regions("drawer_handle")
    return mesh, [v[np.all((v >= boxes[k][0]) & (v <= boxes[k][1]), axis=1)]
                  for k in ("grip", "left_foot", "right_foot")]


def cabinet_boxes(spec: CabinetSpec) -> tuple[list, list]:
    """``(body, drawer)``: lists of ``(center, half_size)`` boxes in the world frame, drawer closed."""
    w, h, t = spec.front_size
    fx, z0, d, bw, bh = spec.front_x, spec.drawer_z, spec.depth, spec.body_width, spec.body_height
    gap, wall = 0.004, 0.015
    back = fx + t + d + 2 * gap
    body_top = max(bh, z0 + h / 2 + wall + gap)
    inner_lo, inner_hi = z0 - h / 2 + gap, z0 + h / 2 - gap  # drawer box (inside the opening)
    body = [
        ((fx + t + (back + wall - fx - t) / 2, -bw / 2 + wall / 2, body_top / 2), ((back + wall - fx - t) / 2, wall / 2, body_top / 2)),
        ((fx + t + (back + wall - fx - t) / 2, bw / 2 - wall / 2, body_top / 2), ((back + wall - fx - t) / 2, wall / 2, body_top / 2)),
        ((fx + t + (back + wall - fx - t) / 2, 0.0, body_top - wall / 2), ((back + wall - fx - t) / 2, bw / 2 - wall, wall / 2)),
        ((back + wall / 2, 0.0, body_top / 2), (wall / 2, bw / 2 - wall, body_top / 2 - wall)),
        # the shelf under the drawer and the closed front below it
        ((fx + t + (back - fx - t) / 2, 0.0, inner_lo - gap - wall / 2), ((back - fx - t) / 2, bw / 2 - wall, wall / 2)),
        ((fx + t + wall / 2, 0.0, (inner_lo - gap - wall) / 2), (wall / 2, bw / 2 - wall, (inner_lo - gap - wall) / 2)),
    ]
    iw = bw / 2 - wall - gap  # half inner width of the drawer box
    drawer = [
        ((fx + t / 2, 0.0, z0), (t / 2, w / 2, h / 2)),                                  # front
        ((fx + t + d / 2, 0.0, inner_lo + 0.005), (d / 2, iw, 0.005)),                   # bottom
        ((fx + t + d / 2, -iw + 0.005, (inner_lo + inner_hi) / 2), (d / 2, 0.005, (inner_hi - inner_lo) / 2)),
        ((fx + t + d / 2, iw - 0.005, (inner_lo + inner_hi) / 2), (d / 2, 0.005, (inner_hi - inner_lo) / 2)),
        ((fx + t + d - 0.005, 0.0, (inner_lo + inner_hi) / 2), (0.005, iw - 0.01, (inner_hi - inner_lo) / 2)),
    ]
    return body, drawer


@register_env("GRT-Drawer-v1", max_episode_steps=500)
class DrawerEnv(TaskEnv):
    """Panda + procedural cabinet + one in-memory handle on the drawer. See the module docstring.

    Args:
        grasp_point: the *nominal* handle's grasp point (m) in the handle frame.
        cabinet: :class:`CabinetSpec` fields (dict) to override.
        qpos_noise: uniform noise (rad) of the 7 arm joints at reset (paper: 0.25).
        success_opening: opening (m) that ends the episode as a success.
        handle_friction, handle_density: the handle's material.
        sim_freq, control_freq: physics and control rates (Hz).
    """

    object_word = "handle"

    SUPPORTED_ROBOTS = ["panda_drawer"]
    agent: PandaDrawer
    robot_base = (0.0, 0.0, 0.0)

    def __init__(self, *args, grasp_point=(0.0, 0.0, 0.032), cabinet: dict | None = None,
                 qpos_noise: float = 0.25, success_opening: float = 0.38, handle_friction: float = 1.0,
                 handle_density: float = 2000.0, sim_freq: int = 120, control_freq: int = 60, **kwargs):
        self.cabinet = CabinetSpec(**(cabinet or {}))
        self.grasp_point = np.asarray(grasp_point, np.float64).reshape(3)
        self.qpos_noise, self.success_opening = float(qpos_noise), float(success_opening)
        self.handle_friction, self.handle_density = float(handle_friction), float(handle_density)
        self._sim_freq, self._control_freq = int(sim_freq), int(control_freq)
        self.rest_qpos = None
        self.set_object(*default_handle())
        super().__init__(*args, robot_uids="panda_drawer", **kwargs)

    # ------------------------------------------------------------------ configuration
    @property
    def _default_human_render_camera_configs(self) -> CameraConfig:
        c = self.cabinet
        pose = sapien_utils.look_at([c.front_x - 0.55, 0.55, c.drawer_z + 0.35], [c.front_x - 0.1, 0.0, c.drawer_z])
        return CameraConfig("render_camera", pose, 512, 512, 0.9, 0.01, 10)

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict):
        self.ground = build_ground(self.scene)
        cabinets, shapes, self.hull_tally = [], [], new_tally()
        for i, j in enumerate(self.object_of_env()):
            art, built = build_cabinet(self.scene, self.cabinet, self.object_meshes[j], self.object_parts_of[j],
                                       self.handle_friction, self.handle_density, scene_idxs=[i], name=f"cabinet_{i}",
                                       tally=self.hull_tally)
            self.remove_from_state_dict_registry(art)
            cabinets.append(art)
            shapes.append(built)
        self.cabinet_art = Articulation.merge(cabinets, name="cabinet", merge_links=True)
        self.add_to_state_dict_registry(self.cabinet_art)
        self.num_handle_shapes = min(shapes)
        self.drawer_link = self.cabinet_art.links[1]
        self.drawer_joint = self.cabinet_art.active_joints[0]
        self.drawer_joint.set_friction(self.cabinet.friction)

    def _after_reconfigure(self, options: dict):
        from grt.tasks.motion import PandaIK

        robot = self.agent.robot
        self._ik = PandaIK(robot, base=self.robot_root())
        if self.rest_qpos is None:
            self.rest_qpos = rest_qpos(self._ik, self.cabinet, self.grasp_point)
        self._finger_links = [robot.links_map["panda_leftfinger"], robot.links_map["panda_rightfinger"]]

    # ------------------------------------------------------------------ episodes
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        limits = np.asarray(to_numpy(self.agent.robot.get_qlimits())[0], np.float64)
        qs = []
        for seed in self._episode_seed:  # each sub-scene's draws as one env's episode with its seed
            rng = np.random.default_rng(int(seed))
            q = self.rest_qpos.copy()
            q[:7] += rng.uniform(-self.qpos_noise, self.qpos_noise, 7)
            qs.append(np.clip(q, limits[:, 0], limits[:, 1]))
        self.agent.reset(torch.as_tensor(np.stack(qs), dtype=torch.float32, device=self.device))
        self.agent.controller.reset()  # the accumulated joint targets start at the new configuration
        self.cabinet_art.set_qpos(torch.zeros((self.num_envs, 1), device=self.device))
        self.cabinet_art.set_qvel(torch.zeros((self.num_envs, 1), device=self.device))

    # ------------------------------------------------------------------ state, success, reward
    def openings(self) -> np.ndarray:
        """``(N,)`` drawer openings (m)."""
        return to_numpy(self.cabinet_art.get_qpos()[:, 0]).astype(np.float64)

    def opening(self) -> float:
        """Sub-scene 0's drawer opening (m)."""
        return float(self.openings()[0])

    def grasp_worlds(self) -> np.ndarray:
        """``(N, 3)`` world positions (m) of the nominal handle's grasp point (moving with each drawer)."""
        pose = self.cabinet.handle_pose()
        local = pose[:3, :3] @ self.grasp_point + pose[:3, 3]
        shift = np.zeros((self.num_envs, 3))
        shift[:, 0] = -self.openings()
        return local + shift

    def grasp_world(self) -> np.ndarray:
        """Sub-scene 0's grasp point (m, world)."""
        return self.grasp_worlds()[0]

    def finger_contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """``(N,)`` contact force magnitudes (N) between each finger and the drawer link (handle and front)."""
        forces = [to_numpy(torch.linalg.vector_norm(self.scene.get_pairwise_contact_forces(link, self.drawer_link),
                                                    dim=-1)).astype(np.float64)
                  for link in self._finger_links]
        return forces[0], forces[1]

    def drawer_state(self) -> dict[str, np.ndarray]:
        """The drawer and the hand, ``(N,)`` each: opening (m), its velocity, TCP to grasp point (m), ..."""
        tcp = self.tcp_poses()
        left, right = self.finger_contacts()
        qpos = self.agent.robot.get_qpos()
        to_grasp = self.grasp_worlds() - tcp[:, :3, 3]
        return dict(opening=self.openings(), drawer_vel=to_numpy(self.cabinet_art.get_qvel()[:, 0]).astype(np.float64),
                    tcp_to_grasp=np.sqrt(np.vecdot(to_grasp, to_grasp)),
                    finger_width=to_numpy(qpos[:, 7:9].sum(dim=1)).astype(np.float64),
                    holding=(left > 0.5) & (right > 0.5), touching=(left > 0.0) | (right > 0.0))

    def evaluate(self) -> dict:
        if not hasattr(self, "cabinet_art"):
            return dict(success=torch.zeros(self.num_envs, dtype=torch.bool, device=self.device))
        s = self.drawer_state()
        out = {k: torch.as_tensor(v, dtype=torch.bool if v.dtype == bool else torch.float32, device=self.device)
               for k, v in s.items()}
        return dict(success=torch.as_tensor(s["opening"] >= self.success_opening, device=self.device), **out)

    def compute_dense_reward(self, obs, action, info):
        """``0.1 x (-0.5 tanh(d / 0.1) - 2 (1 - opening / 0.39) + 0.25 holding + 10 success - 0.01 |a|^2)``.

        ``d``: TCP to the nominal grasp point (m). Every step costs until the drawer is open and the
        episode ends at success, so finishing sooner pays (a positive per-step reward for a partly open
        drawer would pay the policy to stop short of the end). Scaled by 0.1 so that returns stay
        within about -100..1 (PPO's value targets; rsl-rl does not normalize rewards).
        """
        reach = -0.5 * torch.tanh(info["tcp_to_grasp"].float() / 0.1)
        closed = 1.0 - info["opening"].float() / MAX_OPENING
        act = torch.as_tensor(action, dtype=torch.float32, device=self.device).reshape(self.num_envs, -1)
        return 0.1 * (reach - 2.0 * closed + 0.25 * info["holding"].float() + 10.0 * info["success"].float()
                      - 0.01 * (act ** 2).sum(-1))

    def task_obs(self) -> dict[str, np.ndarray]:
        """The policy's observation (see the module docstring), batched: ``state`` (N, 23)."""
        robot = self.agent.robot
        qpos, qvel = to_numpy(robot.get_qpos()), to_numpy(robot.get_qvel())
        to_grasp = self.grasp_worlds() - self.tcp_poses()[:, :3, 3]
        drawer = np.stack([self.openings(), to_numpy(self.cabinet_art.get_qvel()[:, 0]).astype(np.float64)], axis=1)
        return {"state": np.concatenate([qpos, 0.1 * qvel, to_grasp, drawer], axis=1).astype(np.float32)}


def build_cabinet(scene, spec: CabinetSpec, handle: trimesh.Trimesh, parts: list[np.ndarray],
                  handle_friction: float = 1.0, handle_density: float = 2000.0, scene_idxs: list[int] | None = None,
                  name: str = "cabinet", tally: dict | None = None):
    """Build the cabinet articulation (fixed body, one prismatic drawer carrying the handle).

    ``scene_idxs``: the parallel sub-scenes to build it in (``None``: all); ``name``: the articulation's;
    ``tally``: a :func:`grt.tasks.scene.new_tally` record of the handle's hulls.

    Returns:
        ``(articulation, number of handle collision shapes built)``.

    Raises:
        ValueError: a handle part that does not build into a collision shape.
    """
    builder = scene.create_articulation_builder()
    builder.initial_pose = sapien.Pose()
    if scene_idxs is not None:
        builder.set_scene_idxs(list(scene_idxs))
    wood = physx.PhysxMaterial(static_friction=0.5, dynamic_friction=0.5, restitution=0.0)
    body_boxes, drawer_boxes = cabinet_boxes(spec)
    body = builder.create_link_builder()
    body.set_name("cabinet_body")
    for center, half in body_boxes:
        body.add_box_collision(sapien.Pose(p=center), half_size=half, material=wood)
        body.add_box_visual(sapien.Pose(p=center), half_size=half,
                            material=sapien.render.RenderMaterial(base_color=(0.72, 0.62, 0.48, 1.0)))
    drawer = builder.create_link_builder(body)
    drawer.set_name("drawer")
    for center, half in drawer_boxes:
        drawer.add_box_collision(sapien.Pose(p=center), half_size=half, material=wood, density=300.0)
        drawer.add_box_visual(sapien.Pose(p=center), half_size=half,
                              material=sapien.render.RenderMaterial(base_color=(0.80, 0.70, 0.55, 1.0)))
    # The handle: convex parts posed on the drawer front (drawer link frame = world at opening 0).
    pose = spec.handle_pose()
    posed = [np.asarray(p, np.float64) @ pose[:3, :3].T + pose[:3, 3] for p in parts]
    metal = physx.PhysxMaterial(static_friction=handle_friction, dynamic_friction=handle_friction, restitution=0.0)
    counted = {"n": 0}
    base_build = drawer.build_physx_component

    def build_with_handle(link_parent=None):
        component = base_build(link_parent)
        counted["n"] = attach_convex_parts(component, posed, metal, handle_density, drawer.collision_groups,
                                           GPU_INFLATION if scene.gpu_sim_enabled else CPU_INFLATION, tally)
        return component

    drawer.build_physx_component = build_with_handle
    if scene.can_render():
        posed_mesh = handle.copy()
        posed_mesh.apply_transform(pose)
        drawer._procedural_shapes = [render_mesh_shape(posed_mesh, (0.55, 0.55, 0.6))]
        base_render = drawer.build_render_component

        def render_with_handle():
            component = base_render()
            for shape in drawer._procedural_shapes:
                component.attach(shape)
            return component

        drawer.build_render_component = render_with_handle
    # Prismatic joint along the joint frame's x; the frame is turned 180 deg about z so that a
    # positive opening moves the drawer towards the robot (world -x).
    turn = sapien.Pose(q=[0.0, 0.0, 0.0, 1.0])
    drawer.set_joint_name("drawer_slide")
    drawer.set_joint_properties("prismatic", limits=[[0.0, MAX_OPENING]], pose_in_parent=turn,
                                pose_in_child=turn, friction=spec.friction, damping=spec.damping)
    art = builder.build(name=name, fix_root_link=True)
    if counted["n"] != len(parts):
        raise ValueError(f"only {counted['n']} of {len(parts)} handle collision parts were built")
    return art, counted["n"]


def rest_qpos(ik, spec: CabinetSpec, grasp_point: np.ndarray) -> np.ndarray:
    """The robot's rest pose: the TCP 15 cm before the closed handle's grasp point along the approach."""
    pose = spec.handle_pose()
    target = np.eye(4)
    target[:3, :3] = GRASP_ROT
    target[:3, 3] = pose[:3, :3] @ grasp_point + pose[:3, 3] - 0.15 * APPROACH
    # The arm in its vertical plane (joints 1, 3, 5 at 0), hand horizontal, fingers closing vertically.
    q = None
    for guess in ([0.0, -0.3, 0.0, -2.2, 0.0, 3.0, -np.pi / 4], [0.0, 0.0, 0.0, -1.6, 0.0, 2.8, -np.pi / 4]):
        q = ik.solve(target, np.r_[guess, 0.04, 0.04])
        if q is not None:
            break
    if q is None:
        raise RuntimeError(f"the rest pose {target[:3, 3].round(3).tolist()} has no IK solution: move the cabinet")
    q = q.copy()
    q[7:] = 0.04
    return q
