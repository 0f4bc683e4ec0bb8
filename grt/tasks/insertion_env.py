"""GRT-Insert-v1: a Panda holding a plug above a matched socket inserts it (IndustReal-style).

**Description.** A Franka Panda (base at (-0.615, 0, 0)) starts with a plug pinched between its
fingers, a few centimeters above a socket whose hole is the plug head's cross-section grown by a
clearance (0.4 mm a side) with a 1.5 mm entrance chamfer (:mod:`grt.tasks.socket`). The plug is held
**by friction only**: the fingers are driven closed (PD, force-limited) against its grip, so a plug
whose grip was deformed sits differently in the hand and can slip or turn when it meets the socket.
Actions are 6-D end-effector delta poses in [-1, 1], scaled by 0.01 (m, rad) through ManiSkill's
task-space ``pd_ee_delta_pose`` controller; the gripper is not part of the action (held closed).

**Observations** (:meth:`InsertEnv.task_obs`). ``state`` (24,): 7 arm joint positions, TCP pose
(position, wxyz quaternion), the *noisy* target TCP pose (position with uniform ±1 mm XY noise
drawn per episode, quaternion) and the displacement from the TCP to the noisy target position.
``grip`` (6,): the plug's pose in the hand, as the hand correction that would undo its deviation from
the nominal grip: the transform ``C`` (TCP frame; translation in m, then rotation vector in rad) with
``target TCP @ C`` the TCP pose that puts *this* plug where the nominal grip puts it at the target. Zero
for a plug held as designed; a deformed grip that makes the plug hang crooked shows here (an in-hand
pose estimate, as tactile sensing or a wrist camera gives; ManiSkill's own state observations include
the held object's pose). Policies use it only if they list it in their observation groups.
``cloud`` (``cloud_points``, 3): farthest-point samples of the plug's and the socket's surfaces at
their current poses, relative to the TCP (sampled once per object from the posed meshes, not rendered).

**Randomizations** (per seeded reset). Socket XY uniform ±0.1 m around (0, 0), height 0-0.05 m,
yaw ±0.087 rad; plug above the socket with XY noise ±0.01 m, its tip 10-25 mm above the socket's
top, yaw ±0.087 rad; target XY noise ±1 mm.

**Success.** The plug's tip is within 3 mm (vertically, in the socket frame) of the hole's floor
and within 2 mm of the hole's axis. An episode ends at success or after ``max_episode_steps``.

**Deformable object.** The plug: visual = the candidate mesh, collision = its convex parts, from
memory. The socket is built once from the *nominal* plug (``set_socket``) and never deformed. Swap
the plug with :meth:`InsertEnv.set_object` then ``reset(options={"reconfigure": True})``.

**Parallel sub-scenes** (``num_envs > 1``, ``physx_cuda``). Sub-scene ``i`` holds its own plug
(:meth:`InsertEnv.set_objects`: per-sub-scene builders, then ``Actor.merge``, as ManiSkill's
``pick_single_ycb.py``) and runs the episode of its own seed (``reset(seed=[...])``): every randomization is
drawn from ``numpy.random.default_rng(seed)`` exactly as with one env, so sub-scene ``i`` starts where the
one-env episode with that seed starts. States, observations and flags are ``(num_envs, ...)`` arrays,
computed in float64 on the host as for one env (so the CPU episodes stay bit for bit what they were).
"""

from __future__ import annotations

import numpy as np
import sapien
import torch
import trimesh
from mani_skill.agents.controllers import PDEEPoseControllerConfig
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots import Panda
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.registration import register_env
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.actor import Actor
from mani_skill.utils.structs.pose import Pose
from sapien import physx
from scipy.spatial.transform import Rotation

from grt.tasks.batched import to_numpy
from grt.tasks.env_base import TaskEnv
from grt.tasks.motion import PandaIK
from grt.tasks.scene import InMemoryActorBuilder, build_object_actor, new_tally
from grt.tasks.socket import SocketGeometry, build_socket, grip_half_width

ACTION_SCALE = 0.01  # m and rad per unit action (paper: delta pose scaled by 0.01)
REST_QPOS = np.array([0.0, -0.2847, 0.0, -2.2441, 0.0, 1.9594, np.pi / 4, 0.04, 0.04])
# TCP orientation in the plug frame: approach (TCP z) down the plug's -z, fingers closing along plug y.
TCP_IN_PLUG_ROT = np.diag([1.0, -1.0, -1.0])
STATE_DIM = 24
GRIP_DIM = 6


@register_agent(override=True)  # by uid, so the env's SUPPORTED_ROBOTS check knows it
class PandaInsert(Panda):
    """The Panda with the paper's insertion action: arm-only 6-D delta pose scaled by 0.01; the
    fingers are driven closed by :class:`InsertEnv` (not part of the action)."""

    uid = "panda_insert"

    @property
    def _controller_configs(self):
        arm = PDEEPoseControllerConfig(
            joint_names=self.arm_joint_names, pos_lower=-ACTION_SCALE, pos_upper=ACTION_SCALE,
            rot_lower=-ACTION_SCALE, rot_upper=ACTION_SCALE, stiffness=self.arm_stiffness,
            damping=self.arm_damping, force_limit=self.arm_force_limit, ee_link=self.ee_link_name,
            urdf_path=self.urdf_path)
        return dict(pd_ee_delta_pose=dict(arm=arm))


def pose_matrix(rot: np.ndarray, pos) -> np.ndarray:
    """``(4, 4)`` from a rotation ``(3, 3)`` and a position ``(3,)``."""
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = rot, pos
    return out


def rotvec(rot: np.ndarray) -> np.ndarray:
    """The rotation vector (axis times angle, rad) of a rotation matrix."""
    return Rotation.from_matrix(rot).as_rotvec()


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def default_plug(head_length: float) -> tuple[trimesh.Trimesh, list[np.ndarray]]:
    """The built-in USB-like plug and two convex parts (head, grip): the object before any ``set_object``."""
    from grt.objects import get_object

    mesh = get_object("usb_plug")
    v = np.asarray(mesh.vertices)
    return mesh, [v[v[:, 2] <= head_length + 1e-9], v[v[:, 2] >= head_length - 1e-9]]


def farthest_points(points: np.ndarray, k: int) -> np.ndarray:
    """``k`` farthest-point samples of ``points`` ``(P, 3)``, starting from the first point."""
    k = min(k, len(points))
    chosen = np.zeros(k, np.int64)
    dist = np.linalg.norm(points - points[0], axis=1)
    for i in range(1, k):
        chosen[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i]], axis=1))
    return points[chosen]


@register_env("GRT-Insert-v1", max_episode_steps=256)
class InsertEnv(TaskEnv):
    """Panda + table + socket + one in-memory plug per sub-scene. See the module docstring.

    Args:
        head_length: length (m) of the plug's connector (from its tip at z = 0).
        plug: the plug before any :meth:`set_object` (meters, tip at z = 0); ``None``: the built-in USB plug.
        grip_height: height (m) on the plug of the point between the fingertips in the nominal grip.
        socket_xy_range, socket_z_range, socket_yaw_range: socket randomization (m, m, rad).
        plug_xy_range: XY noise (m) of the plug above the socket; plug_height_range: (low, high) of its
            tip above the socket's top (m); plug_yaw_range: rad.
        target_noise: XY noise (m) of the observed target pose.
        plug_friction, plug_density: the plug's material.
        cloud_points: points in the ``cloud`` observation (0: no cloud).
        sim_freq, control_freq: physics and control rates (Hz).
    """

    object_word = "plug"

    SUPPORTED_ROBOTS = ["panda_insert"]
    agent: PandaInsert
    max_dense_reward = 2.25  # see compute_dense_reward

    def __init__(self, *args, head_length: float = 0.012, grip_height: float = 0.030,
                 socket_xy_range: float = 0.1, socket_z_range: tuple[float, float] = (0.0, 0.05),
                 socket_yaw_range: float = 0.087, plug_xy_range: float = 0.01,
                 plug_height_range: tuple[float, float] = (0.010, 0.025), plug_yaw_range: float = 0.087,
                 target_noise: float = 0.001, plug_friction: float = 1.0, plug_density: float = 1000.0,
                 cloud_points: int = 500, sim_freq: int = 100, control_freq: int = 20,
                 plug: trimesh.Trimesh | None = None, **kwargs):
        self.head_length, self.grip_height = float(head_length), float(grip_height)
        self.socket_xy_range, self.socket_z_range = float(socket_xy_range), tuple(socket_z_range)
        self.socket_yaw_range, self.plug_xy_range = float(socket_yaw_range), float(plug_xy_range)
        self.plug_height_range, self.plug_yaw_range = tuple(plug_height_range), float(plug_yaw_range)
        self.target_noise = float(target_noise)
        self.plug_friction, self.plug_density = float(plug_friction), float(plug_density)
        self.cloud_points = int(cloud_points)
        self._sim_freq, self._control_freq = int(sim_freq), int(control_freq)
        self._ik: PandaIK | None = None
        self._arm_starts: dict[int, np.ndarray | None] = {}  # seed -> IK solution of its start pose
        if plug is None:
            plug, parts = default_plug(self.head_length)
        else:  # the session's nominal plug: the built-in one may have no surface at a user's grip height
            v = np.asarray(plug.vertices)
            parts = [v[v[:, 2] <= self.head_length + 1e-9], v[v[:, 2] >= self.head_length - 1e-9]]
        self.set_socket(build_socket(plug, self.head_length))
        self.set_object(plug, parts)
        super().__init__(*args, robot_uids="panda_insert", **kwargs)

    # ------------------------------------------------------------------ configuration
    @property
    def _default_human_render_camera_configs(self) -> CameraConfig:
        pose = sapien_utils.look_at([0.25, 0.3, 0.3], [0.0, 0.0, 0.08])
        return CameraConfig("render_camera", pose, 512, 512, 0.8, 0.01, 10)

    def set_socket(self, socket: SocketGeometry) -> None:
        """The socket (built from the nominal plug); takes effect at the next reconfigure."""
        self.socket = socket

    def set_objects(self, objects: list[tuple[trimesh.Trimesh, list[np.ndarray]]],
                    assignment: list[int] | None = None) -> None:
        """The next plugs (meters, tip at z = 0, connector down): see :meth:`TaskEnv.set_objects`; each plug's
        surface cloud and grip half-width are made here, once."""
        super().set_objects(objects, assignment)
        self._plug_clouds = np.stack([self._surface_cloud(mesh, self.cloud_points // 2, seed=1)
                                      for mesh in self.object_meshes])
        self._grip_half_widths = np.array([grip_half_width(mesh, self.grip_height) for mesh in self.object_meshes])

    def _surface_cloud(self, mesh: trimesh.Trimesh, k: int, seed: int) -> np.ndarray:
        if k <= 0:
            return np.zeros((0, 3))
        samples, _ = trimesh.sample.sample_surface(mesh, max(20 * k, 2000), seed=seed)
        return farthest_points(np.asarray(samples), k)

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(self, robot_init_qpos_noise=0.0)
        self.table_scene.build()
        material = physx.PhysxMaterial(static_friction=0.5, dynamic_friction=0.5, restitution=0.0)
        self.hull_tally = new_tally()
        builder = InMemoryActorBuilder(self.socket.parts, material, density=1000.0, tally=self.hull_tally)
        builder.set_scene(self.scene)
        if self.scene.can_render():
            m = self.socket.mesh
            builder._procedural_shapes.append(sapien.render.RenderShapeTriangleMesh(
                np.ascontiguousarray(m.vertices, np.float32), np.ascontiguousarray(m.faces, np.uint32),
                np.ascontiguousarray(m.vertex_normals, np.float32), np.zeros((len(m.vertices), 2), np.float32),
                sapien.render.RenderMaterial(base_color=(0.3, 0.3, 0.35, 1.0))))
        builder.initial_pose = sapien.Pose(p=[0.0, 0.0, 0.02])
        self.socket_actor = builder.build_kinematic(name="grt_socket")
        self._env_object = self.object_of_env()
        plugs = [build_object_actor(self.scene, self.object_meshes[j], self.object_parts_of[j], f"grt_plug_{i}",
                                    friction=self.plug_friction, density=self.plug_density, initial_z=0.3,
                                    scene_idxs=[i], tally=self.hull_tally)
                 for i, j in enumerate(self._env_object)]
        for actor in plugs:
            self.remove_from_state_dict_registry(actor)
        self.plug = Actor.merge(plugs, name="grt_plug")
        self.add_to_state_dict_registry(self.plug)
        self._socket_cloud = self._surface_cloud(self.socket.mesh, self.cloud_points - self.cloud_points // 2,
                                                 seed=2)
        # the fingers hold the plug by force (PD, limited); set before the GPU simulation starts
        self._fingers = [j for j in self.agent.robot.get_active_joints() if "finger" in j.name]
        for joint in self._fingers:
            joint.set_drive_properties(stiffness=1e3, damping=1e2, force_limit=100)

    def _after_reconfigure(self, options: dict):
        self._ik = PandaIK(self.agent.robot, base=self.robot_root())

    # ------------------------------------------------------------------ episodes
    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        starts = [self._episode_start(int(seed)) for seed in self._episode_seed]
        self.start_errors = [start.pop("error") for start in starts]
        stack = {k: np.stack([start[k] for start in starts]) for k in starts[0]}
        self.socket_world, self.target_tcp = stack["socket_world"], stack["target_tcp"]
        self._target_obs_pq = stack["target_obs_pq"]
        q = stack["qpos"]
        q[:, 7:] = self._grip_half_widths[self._env_object][:, None]
        self.socket_actor.set_pose(_poses(stack["socket_world"], self.device))
        self.agent.reset(torch.as_tensor(q, dtype=torch.float32, device=self.device))
        for joint in self._fingers:
            joint.set_drive_target(-0.01)
        self.plug.set_pose(_poses(stack["plug_start"], self.device))
        self.plug.set_linear_velocity(torch.zeros((self.num_envs, 3), device=self.device))
        self.plug.set_angular_velocity(torch.zeros((self.num_envs, 3), device=self.device))

    def _episode_start(self, seed: int) -> dict:
        """One episode's seeded start (the draws of ``numpy.random.default_rng(seed)``, in the one-env order):
        socket and target poses, the plug's start pose and the arm's joints there; ``error`` when the start
        pose has no IK solution (the arm then starts at rest, and the trial is a ``sim_error``)."""
        rng = np.random.default_rng(seed)
        sock = self.socket
        xy = rng.uniform(-self.socket_xy_range, self.socket_xy_range, 2)
        top = 0.02 + rng.uniform(*self.socket_z_range)
        yaw = rng.uniform(-self.socket_yaw_range, self.socket_yaw_range)
        # The socket frame: origin at the hole's axis on the top face; the hole center is the plug's axis.
        socket_world = pose_matrix(rot_z(yaw), [xy[0], xy[1], top])
        axis = np.r_[sock.center, 0.0]  # plug-frame XY of the head's axis
        tcp_in_plug = pose_matrix(TCP_IN_PLUG_ROT, [0.0, 0.0, self.grip_height])
        # Inserted: the plug's tip sits on the floor minus the margin, its axis on the hole's axis.
        plug_inserted = socket_world @ pose_matrix(np.eye(3), [0.0, 0.0, -self.head_length]
                                                   ) @ pose_matrix(np.eye(3), -axis)
        target_tcp = plug_inserted @ tcp_in_plug
        noise = np.r_[rng.uniform(-self.target_noise, self.target_noise, 2), 0.0]
        target_obs = target_tcp.copy()
        target_obs[:3, 3] += noise
        t = sapien.Pose(target_obs.astype(np.float32))
        # Start: the plug above the socket, tip 10-25 mm over the top face.
        dxy = rng.uniform(-self.plug_xy_range, self.plug_xy_range, 2)
        height = rng.uniform(*self.plug_height_range)
        plug_yaw = rng.uniform(-self.plug_yaw_range, self.plug_yaw_range)
        plug_start = pose_matrix(rot_z(plug_yaw), [xy[0] + dxy[0], xy[1] + dxy[1], top + height]
                                 ) @ pose_matrix(np.eye(3), -axis)
        tcp_start = plug_start @ tcp_in_plug
        if seed not in self._arm_starts:  # the same start pose for every plug: solved once per seed
            self._arm_starts[seed] = self._ik.solve(tcp_start, REST_QPOS)
        q, error = self._arm_starts[seed], None
        if q is None:
            q = REST_QPOS
            error = f"RuntimeError: no IK solution for the start pose {tcp_start[:3, 3].round(3).tolist()}"
        return dict(socket_world=socket_world, target_tcp=target_tcp, plug_start=plug_start, qpos=q.copy(),
                    target_obs_pq=np.concatenate([t.p, t.q]).astype(np.float32), error=error)

    # ------------------------------------------------------------------ state, success, reward
    def plug_poses(self) -> np.ndarray:
        """``(N, 4, 4)`` world poses of the plug frames (tip at their origin)."""
        return to_numpy(self.plug.pose.to_transformation_matrix()).astype(np.float64)

    def plug_pose(self) -> np.ndarray:
        """``(4, 4)`` world pose of sub-scene 0's plug frame."""
        return self.plug_poses()[0]

    def keypoints(self) -> tuple[np.ndarray, np.ndarray]:
        """Plug keypoints and their targets ``(N, 2, 3)`` each (m): the head's tip and its top, on its axis."""
        axis = np.r_[self.socket.center, 0.0]
        local = np.stack([axis, axis + [0.0, 0.0, self.head_length]])
        plug = self.plug_poses()
        now = local @ np.swapaxes(plug[:, :3, :3], 1, 2) + plug[:, None, :3, 3]
        inserted = self.target_tcp @ np.linalg.inv(pose_matrix(TCP_IN_PLUG_ROT, [0.0, 0.0, self.grip_height]))
        return now, local @ np.swapaxes(inserted[:, :3, :3], 1, 2) + inserted[:, None, :3, 3]

    def insertion_state(self) -> dict[str, np.ndarray]:
        """Where each plug is relative to its hole (socket frame, m) and whether it is still held, ``(N,)`` each."""
        now, target = self.keypoints()
        inv = np.linalg.inv(self.socket_world)
        tip = (inv[:, :3, :3] @ now[:, 0, :, None])[..., 0] + inv[:, :3, 3]
        depth_to_floor = tip[:, 2] + self.socket.depth
        plug, tcp = self.plug_poses(), self.tcp_poses()
        grip_point = (plug[:, :3, :3] @ np.array([[0.0], [0.0], [self.grip_height]]))[..., 0] + plug[:, :3, 3]
        tilt = np.degrees(np.arccos(np.clip(plug[:, 2, 2], -1.0, 1.0)))
        return dict(tip_to_floor=depth_to_floor, tip_off_axis=_norms(tip[:, :2]),
                    keypoint_error=np.linalg.norm(now - target, axis=-1).mean(axis=-1),
                    grip_offset=_norms(grip_point - tcp[:, :3, 3]), tilt_deg=tilt,
                    pinched=to_numpy(self.agent.is_grasping(self.plug)).astype(bool))

    def evaluate(self) -> dict:
        if self.socket is None or not hasattr(self, "target_tcp"):
            return dict(success=torch.zeros(self.num_envs, dtype=torch.bool, device=self.device))
        s = self.insertion_state()
        success = (s["tip_to_floor"] < 0.003) & (s["tip_off_axis"] < 0.002)
        out = {k: torch.as_tensor(v, dtype=torch.bool if v.dtype == bool else torch.float32, device=self.device)
               for k, v in s.items()}
        return dict(success=torch.as_tensor(success, device=self.device), **out)

    def compute_dense_reward(self, obs, action, info):
        """``-tanh(keypoint error / 2 cm)`` (in [-1, 0]) + 0.25 while the tip is in the hole + 2 at success."""
        err = info["keypoint_error"].float()
        engaged = (info["tip_to_floor"] < self.head_length) & (info["tip_off_axis"] < 0.002)
        return -torch.tanh(err / 0.02) + 0.25 * engaged.float() + 2.0 * info["success"].float()

    def grip_correction(self) -> np.ndarray:
        """``grip`` ``(N, 6)``: the in-hand correction ``C`` of the module docstring (m, rad), float32."""
        plug_in_tcp = np.linalg.inv(self.tcp_poses()) @ self.plug_poses()
        tcp_in_plug = pose_matrix(TCP_IN_PLUG_ROT, [0.0, 0.0, self.grip_height])
        c = np.linalg.inv(tcp_in_plug) @ np.linalg.inv(plug_in_tcp)
        return np.concatenate([c[:, :3, 3], rotvec(c[:, :3, :3])], axis=1).astype(np.float32)

    def task_obs(self) -> dict[str, np.ndarray]:
        """The policy's observations (see the module docstring), batched: ``state`` (N, 24), ``grip`` (N, 6),
        ``cloud`` (N, P, 3)."""
        qpos = to_numpy(self.agent.robot.get_qpos())[:, :7]
        tcp = to_numpy(self.agent.tcp.pose.raw_pose)
        target = self._target_obs_pq
        state = np.concatenate([qpos, tcp, target, target[:, :3] - tcp[:, :3]], axis=1).astype(np.float32)
        out = {"state": state, "grip": self.grip_correction()}
        if self.cloud_points:
            plug, sock = self.plug_poses(), self.socket_world
            clouds = self._plug_clouds[self._env_object]
            cloud = np.concatenate([clouds @ np.swapaxes(plug[:, :3, :3], 1, 2) + plug[:, None, :3, 3],
                                    self._socket_cloud @ np.swapaxes(sock[:, :3, :3], 1, 2) + sock[:, None, :3, 3]],
                                   axis=1)
            out["cloud"] = (cloud - tcp[:, None, :3]).astype(np.float32)
        return out


def _poses(matrices: np.ndarray, device) -> Pose:
    """A batched ManiSkill pose from ``(N, 4, 4)`` matrices, each converted as ``sapien.Pose`` converts one."""
    return Pose.create([sapien.Pose(m.astype(np.float32)) for m in matrices], device=device)


def _norms(vectors: np.ndarray) -> np.ndarray:
    """``(N,)`` Euclidean norms of ``(N, D)`` rows, each as ``np.linalg.norm`` of the row alone computes it."""
    return np.sqrt(np.vecdot(vectors, vectors))
