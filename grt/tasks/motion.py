"""Inverse kinematics and joint-space motion for the Panda (SAPIEN's Pinocchio model; no mplib).

IK is Pinocchio's closed-loop IK (damped least squares, as the paper's DLS solver) on the articulation
the simulator uses, so the kinematics match exactly; solutions outside the joint limits are rejected.
"""

from __future__ import annotations

import numpy as np
import sapien

ARM_DOF = 7


def rotate_about_z(pose: np.ndarray, angle: float) -> np.ndarray:
    """``pose @ Rz(angle)``: the same grasp turned about its approach axis. pose: ``(4, 4)``."""
    c, s = np.cos(angle), np.sin(angle)
    rz = np.eye(4)
    rz[:2, :2] = [[c, -s], [s, c]]
    return pose @ rz


def offset_along_approach(pose: np.ndarray, distance: float) -> np.ndarray:
    """The pose moved ``distance`` (m) along its own z (approach) axis. pose: ``(4, 4)``."""
    out = pose.copy()
    out[:3, 3] += distance * pose[:3, 2]
    return out


def translated(pose: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """The pose translated by a world-frame ``delta`` (3,) in meters."""
    out = pose.copy()
    out[:3, 3] += delta
    return out


class PandaIK:
    """IK of one link (default: the TCP) of a ManiSkill Panda (its first sub-scene's; all share the kinematics).

    Args:
        robot: the ManiSkill ``Articulation`` (single env).
        ee_link: link whose pose is solved for.
        max_iterations: CLIK iterations per solve.
        tolerance: accepted se(3) error norm.
        base: the robot's root pose in its (sub-)scene (``None``: read from the simulator, which a GPU
            simulation does not allow).
    """

    def __init__(self, robot, ee_link: str = "panda_hand_tcp", max_iterations: int = 300,
                 tolerance: float = 1e-3, base: sapien.Pose | None = None):
        articulation = robot._objs[0]
        self.model = articulation.create_pinocchio_model()
        names = [link.name for link in articulation.links]
        self.ee_index = next(i for i, n in enumerate(names) if n == ee_link or n.endswith("_" + ee_link))
        self.base_inv = (articulation.root_pose if base is None else base).inv()
        limits = np.asarray(articulation.get_qlimits(), np.float64)
        self.lower, self.upper = limits[:, 0], limits[:, 1]
        self.mask = np.array([1] * ARM_DOF + [0] * (len(limits) - ARM_DOF), np.int32)
        self.max_iterations, self.tolerance = int(max_iterations), float(tolerance)

    def solve(self, pose: np.ndarray, q_init: np.ndarray) -> np.ndarray | None:
        """Joint positions ``(dof,)`` putting the link at ``pose`` ((4, 4), world), or None.

        Args:
            pose: target link pose in the world frame.
            q_init: ``(dof,)`` initial guess (rad; fingers in m), e.g. the current configuration.
        """
        target = self.base_inv * sapien.Pose(pose.astype(np.float32))
        q, ok, err = self.model.compute_inverse_kinematics(
            self.ee_index, target, initial_qpos=np.asarray(q_init, np.float64), active_qmask=self.mask,
            max_iterations=self.max_iterations)
        q = np.asarray(q, np.float64).reshape(-1)
        if not np.all(np.isfinite(q)) or np.linalg.norm(err) > self.tolerance:
            return None
        arm = q[:ARM_DOF]
        if np.any(arm < self.lower[:ARM_DOF] - 1e-4) or np.any(arm > self.upper[:ARM_DOF] + 1e-4):
            return None
        return q

    def forward(self, q: np.ndarray) -> np.ndarray:
        """World ``(4, 4)`` pose of the link at joint positions ``q`` ``(dof,)``."""
        self.model.compute_forward_kinematics(np.asarray(q, np.float64))
        return (self.base_inv.inv() * self.model.get_link_pose(self.ee_index)).to_transformation_matrix()
