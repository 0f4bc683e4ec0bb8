"""GRT-Grasp-v1: a Panda grasps one object on a table, lifts it and shakes it.

**Description.** A Franka Panda stands at the edge of a table (ManiSkill's ``TableSceneBuilder``,
table top at z = 0, robot base at (-0.615, 0, 0)). One rigid object rests near the table's origin.
The policy sees a segmented, world-frame point cloud of the object fused from ``num_cameras`` depth
cameras on a hemisphere around it (rendered once per trial, on request, not every step; ManiSkill's
"minimal" shader, so depth is quantized to 1 mm; the object's pixels are picked by its segmentation
id, so the robot occludes but never pollutes the cloud); the task
(:class:`grt.tasks.grasp.GraspSession`) executes its grasp: approach from a 5 cm pre-grasp offset,
close, lift 10 cm, shake 10 cm sideways and back.

**Randomizations** (per seeded reset). Object XY uniform in ``±xy_range`` m (0.02 as in the paper),
yaw uniform in ``±yaw_range`` rad (0.79). The robot starts in one fixed configuration (no noise),
its hand 0.38 m above the table.
The object is dropped from 1 mm above its resting height and settles before the policy acts.

**Success.** After the shake the object is above its resting height by at least half the lift and
both fingers press on it (:meth:`evaluate` gives the same flags per step).

**Deformable object.** The object is the actor ``self.obj``: visual = the candidate mesh, collision
= its convex parts, both built from memory (never from a file path: SAPIEN caches meshes by path).
Swap it with :meth:`GraspEnv.set_object` followed by ``reset(options={"reconfigure": True})``.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh
from mani_skill.agents.robots import Panda
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.registration import register_env
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs.pose import Pose

from grt.tasks.env_base import TaskEnv
from grt.tasks.scene import build_object_actor, capture_segmented_cloud, hemisphere_camera_configs

# Fixed start: hand pointing down, TCP at (-0.15, 0, 0.38) m, clear of objects up to ~0.3 m tall and of
# the cameras' view (ManiSkill's "rest" keyframe puts the TCP at z = 0.17 m, inside a standing bottle).
ROBOT_REST_QPOS = np.array([0.0, -0.2847, 0.0, -2.2441, 0.0, 1.9594, np.pi / 4, 0.04, 0.04])
OBJECT_CENTER = (0.0, 0.0, 0.05)  # where the cameras look (m, world)
# The render camera (report videos, grt.evaluate render=true) frames the object and the room its grasp needs
# (lift and shake 0.10 m each, the shake along +y; the closed hand above it), seen from the front right and
# above: a fixed camera on the whole table showed a mug as a few percent of the frame (issue 40).
VIEW_FROM = np.array([0.45, 0.55, 0.35])  # direction from the object to the camera
RENDER_FOV = 0.9  # rad
LIFT_SHAKE_ROOM = (0.10, 0.10, 0.04)  # m: lift, shake, the hand above the object
PLACEMENT_MARGIN = 0.025  # m: the placement noise (xy_range 0.02) and a little air


def framing_camera(mesh: trimesh.Trimesh, fov: float = RENDER_FOV) -> tuple[np.ndarray, np.ndarray]:
    """``(eye, target)`` (m, world) of a camera with field of view ``fov`` (rad, square image) looking along
    ``-VIEW_FROM`` at ``mesh`` (resting on the table, as placed): as close as it can be with the object and
    the room of its lift and shake (:data:`LIFT_SHAKE_ROOM`) all in view."""
    lo, hi = np.asarray(mesh.bounds, np.float64)
    lift, shake, hand = LIFT_SHAKE_ROOM
    room_lo = np.array([lo[0] - PLACEMENT_MARGIN, lo[1] - PLACEMENT_MARGIN, 0.0])
    room_hi = np.array([hi[0] + PLACEMENT_MARGIN, hi[1] + shake + PLACEMENT_MARGIN, hi[2] - lo[2] + lift + hand])
    target = (room_lo + room_hi) / 2
    back = VIEW_FROM / np.linalg.norm(VIEW_FROM)  # from the target to the eye
    right = np.cross([0.0, 0.0, 1.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    corners = np.array([[x, y, z] for x in (room_lo[0], room_hi[0]) for y in (room_lo[1], room_hi[1])
                        for z in (room_lo[2], room_hi[2])]) - target
    reach = np.tan(fov / 2)  # half the view's width at unit depth; a corner at depth d needs |offset| <= reach d
    distance = float(np.max(corners @ back + np.maximum(np.abs(corners @ right), np.abs(corners @ up)) / reach))
    return target + distance * back, target


def default_object() -> tuple[trimesh.Trimesh, list[np.ndarray]]:
    """A 6 cm x 10 cm cylinder standing on z = 0 and its single convex part (the placeholder object)."""
    mesh = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=32)
    mesh.apply_translation([0.0, 0.0, 0.05])
    return mesh, [np.asarray(mesh.vertices)]


@register_env("GRT-Grasp-v1", max_episode_steps=200)
class GraspEnv(TaskEnv):
    """Panda + table + one in-memory object. See the module docstring.

    Args:
        num_cameras: depth cameras on the hemisphere (the paper: 6).
        camera_width, camera_height: image size in pixels (the paper: 360 x 240).
        xy_range: half-range (m) of the uniform XY placement noise.
        yaw_range: half-range (rad) of the uniform yaw noise.
        object_friction: static = dynamic friction of the object.
        object_density: kg/m^3 of the object's collision parts.
        sim_freq, control_freq: physics and control rates (Hz).
        evaluate_every_step: compute :meth:`evaluate` (contact forces) in every ``step``; the grasp
            session turns it off (it judges at phase ends) and saves ~0.1 s per trial.
    """

    SUPPORTED_ROBOTS = ["panda"]
    agent: Panda

    def __init__(self, *args, robot_uids: str = "panda", num_cameras: int = 6, camera_width: int = 360,
                 camera_height: int = 240, xy_range: float = 0.02, yaw_range: float = 0.79,
                 object_friction: float = 1.0, object_density: float = 500.0, sim_freq: int = 100,
                 control_freq: int = 20, evaluate_every_step: bool = True, **kwargs):
        self.num_cameras, self.camera_size = int(num_cameras), (int(camera_width), int(camera_height))
        self.xy_range, self.yaw_range = float(xy_range), float(yaw_range)
        self.object_friction, self.object_density = float(object_friction), float(object_density)
        self._sim_freq, self._control_freq = int(sim_freq), int(control_freq)
        self.object_mesh, self.object_parts = default_object()
        self.rest_z = 0.0
        self.evaluate_every_step = bool(evaluate_every_step)
        super().__init__(*args, robot_uids=robot_uids, **kwargs)

    @property
    def _default_sensor_configs(self) -> list[CameraConfig]:
        width, height = self.camera_size
        return hemisphere_camera_configs(self.num_cameras, OBJECT_CENTER, width=width, height=height)

    @property
    def _default_human_render_camera_configs(self) -> CameraConfig:
        return CameraConfig("render_camera", self.video_camera(self.object_mesh)["pose"], 512, 512, RENDER_FOV,
                            0.01, 10)

    def video_camera(self, mesh: trimesh.Trimesh) -> dict:
        """The render camera's settings that frame ``mesh`` and its grasp (:func:`framing_camera`): ``pose``
        and ``fov``, for ``human_render_camera_configs`` (the report films a CrashShape and the nominal object
        with the nominal's, so both clips show the same view)."""
        eye, target = framing_camera(mesh)
        return {"pose": sapien_utils.look_at(eye.tolist(), target.tolist()), "fov": RENDER_FOV}

    def set_object(self, mesh: trimesh.Trimesh, parts: list[np.ndarray]) -> None:
        """Store the next object; it is built at the next ``reset(options={"reconfigure": True})``.

        Args:
            mesh: visual mesh (m), z up, resting on z = 0.
            parts: convex collision parts, each ``(K, 3)`` (m) in the mesh frame.
        """
        if len(parts) == 0:
            raise ValueError("an object needs at least one convex collision part")
        self.object_mesh = mesh
        self.object_parts = [np.asarray(p, np.float64).reshape(-1, 3) for p in parts]

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(self, robot_init_qpos_noise=0.0)
        self.table_scene.build()
        # Rest the lowest collision vertex 1 mm above the table so the object drops onto it.
        self.rest_z = 0.001 - min(float(p[:, 2].min()) for p in self.object_parts)
        self.obj = build_object_actor(self.scene, self.object_mesh, self.object_parts, "grt_object",
                                      friction=self.object_friction, density=self.object_density,
                                      initial_z=self.rest_z)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            self.table_scene.initialize(env_idx)
            self.agent.reset(torch.as_tensor(ROBOT_REST_QPOS, dtype=torch.float32)[None])
            rng = np.random.default_rng(int(self._episode_seed[0]))
            xy = rng.uniform(-self.xy_range, self.xy_range, size=2)
            yaw = rng.uniform(-self.yaw_range, self.yaw_range)
            quat = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
            pose = Pose.create_from_pq(p=torch.tensor([[xy[0], xy[1], self.rest_z]]),
                                       q=torch.tensor([quat], dtype=torch.float32))
            self.obj.set_pose(pose)
            self.obj.set_linear_velocity(torch.zeros((1, 3)))
            self.obj.set_angular_velocity(torch.zeros((1, 3)))
            self.placement = dict(x=float(xy[0]), y=float(xy[1]), yaw=float(yaw))

    def capture_object_cloud(self) -> tuple[np.ndarray, np.ndarray]:
        """Render every depth camera once; return the object's ``(P, 3)`` points and viewpoints (m)."""
        seg_id = int(self.obj.per_scene_id[0])
        return capture_segmented_cloud(self.scene, self._sensors, seg_id)

    def capture_scene_cloud(self, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The object's points and viewpoints, plus the table-top points seen within ``radius`` (m,
        horizontally) of the object's points' center: the scene a grasp network trained on cluttered
        tables expects."""
        seg_id = int(self.obj.per_scene_id[0])
        table_id = int(self.table_scene.table.per_scene_id[0])
        points, views, table = capture_segmented_cloud(self.scene, self._sensors, seg_id, (table_id,))
        if len(points):
            center = points[:, :2].mean(axis=0)
            table = table[np.linalg.norm(table[:, :2] - center, axis=1) < radius]
        return points, views, table

    def evaluate(self) -> dict:
        if not self.evaluate_every_step:
            return {}
        is_grasped = self.agent.is_grasping(self.obj)
        lifted = self.obj.pose.p[:, 2] > self.rest_z + 0.05
        return dict(is_grasped=is_grasped, lifted=lifted, success=is_grasped & lifted)

    def _get_obs_extra(self, info: dict) -> dict:
        return dict(tcp_pose=self.agent.tcp.pose.raw_pose, obj_pose=self.obj.pose.raw_pose)

    def compute_dense_reward(self, obs, action, info):
        if "success" not in info:
            return torch.zeros(self.num_envs, device=self.device)
        return info["success"].float()
