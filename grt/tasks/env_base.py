"""What GRT's ManiSkill envs share: :class:`TaskEnv`, the base of GRT-Grasp-v1, GRT-Insert-v1, GRT-Drawer-v1.

Each env sets ``_sim_freq`` / ``_control_freq`` (Hz, from its constructor) before ``BaseEnv.__init__``
and its robot's base position in :attr:`TaskEnv.robot_base`; the base turns them into ManiSkill's
hooks. An env has no sensors unless it declares some (the grasp env's depth cameras), gives the task's
policies no ManiSkill observations (its session builds them: ``task_obs``), and normalizes its dense
reward by :attr:`TaskEnv.max_dense_reward`.
"""

from __future__ import annotations

import numpy as np
import sapien
import trimesh
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils.structs.types import SimConfig


class TaskEnv(BaseEnv):
    """The ManiSkill hooks GRT's task envs share (see the module docstring)."""

    #: world position (m) of the robot's base.
    robot_base: tuple[float, float, float] = (-0.615, 0.0, 0.0)
    #: the dense reward's largest value: ``compute_normalized_dense_reward`` divides by it.
    max_dense_reward: float = 1.0
    _sim_freq: int
    _control_freq: int

    @property
    def _default_sim_config(self):
        return SimConfig(sim_freq=self._sim_freq, control_freq=self._control_freq)

    @property
    def _default_sensor_configs(self) -> list[CameraConfig]:
        return []

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose(p=list(self.robot_base)))

    def _get_obs_extra(self, info: dict) -> dict:
        return {}

    def compute_normalized_dense_reward(self, obs, action, info):
        reward = self.compute_dense_reward(obs, action, info)
        return reward if self.max_dense_reward == 1.0 else reward / self.max_dense_reward

    # ------------------------------------------------------------------ the objects of the sub-scenes
    #: what the task's object is called in messages (``plug``, ``handle``)
    object_word: str = "object"

    def set_object(self, mesh: trimesh.Trimesh, parts: list[np.ndarray]) -> None:
        """The next object of every sub-scene (meters, the task's object frame) and its convex parts ``(K, 3)``."""
        self.set_objects([(mesh, parts)])

    def set_objects(self, objects: list[tuple[trimesh.Trimesh, list[np.ndarray]]],
                    assignment: list[int] | None = None) -> None:
        """The next objects: sub-scene ``i`` holds ``objects[assignment[i]]`` (``None``: every one the first);
        takes effect at the next reconfigure (``object_meshes``, ``object_parts_of``: float64 ``(K, 3)``)."""
        if any(len(parts) == 0 for _, parts in objects):
            raise ValueError(f"a {self.object_word} needs at least one convex collision part")
        self.object_meshes = [mesh for mesh, _ in objects]
        self.object_parts_of = [[np.asarray(p, np.float64).reshape(-1, 3) for p in parts] for _, parts in objects]
        self._assignment = None if assignment is None else np.asarray(assignment, np.int64)

    def object_of_env(self) -> np.ndarray:
        """``(num_envs,)`` index of each sub-scene's object in the objects given to :meth:`set_objects`."""
        if self._assignment is None:
            return np.zeros(self.num_envs, np.int64)
        if len(self._assignment) != self.num_envs:
            raise ValueError(f"set_objects gave {len(self._assignment)} sub-scene assignments for "
                             f"{self.num_envs} sub-scenes")
        return self._assignment

    def robot_root(self) -> sapien.Pose | None:
        """The robot's root pose for IK (:class:`grt.tasks.motion.PandaIK`): ``None`` on the CPU, where the
        solver reads the simulator's (its float noise included, as every CPU episode so far), the configured
        base on the GPU, whose simulation gives no per-object CPU poses."""
        return sapien.Pose(p=list(self.robot_base)) if self.gpu_sim_enabled else None

    def tcp_poses(self) -> np.ndarray:
        """``(num_envs, 4, 4)`` world poses of the robots' TCPs (m), float64 on the host."""
        pose = self.agent.tcp.pose.to_transformation_matrix()
        return pose.detach().cpu().numpy().astype(np.float64)

    def tcp_pose(self) -> np.ndarray:
        """``(4, 4)`` world pose of sub-scene 0's TCP (m)."""
        return self.tcp_poses()[0]
