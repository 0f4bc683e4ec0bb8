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
