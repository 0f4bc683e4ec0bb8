"""An analytic drawer-opening policy: reach, pinch and pull with Jacobian joint deltas (a baseline).

It reads only the task's 23-D ``state`` (:mod:`grt.tasks.drawer_env`; its action and grasp conventions
in :mod:`grt.policies.drawer_action`): joint positions, the vector from
the TCP to the *nominal* handle's grasp point and the drawer's opening. Forward kinematics and the
Jacobian come from the Panda's own URDF (SAPIEN's Pinocchio model, robot base at the world origin as in
``GRT-Drawer-v1``). Stateless, so it can teach a learned policy (behaviour cloning warm start):

1. fingers open, the TCP goes to a point 8 cm before the grasp point along the approach, then in;
2. at the grasp point (within 1.2 cm) the fingers close;
3. once closed, the TCP moves towards the robot (the drawer's opening direction), until the drawer is open.

Like the learned policy it never sees the handle's geometry, so a deformed handle makes it miss or slip.
"""

from __future__ import annotations

import numpy as np

from grt.policies.base import BatchedPolicy
from grt.policies.drawer_action import APPROACH, ARM_DELTA, FINGER_DELTA, GRASP_ROT

ARM_JOINTS = [f"panda_joint{i}" for i in range(1, 8)] + ["panda_finger_joint1", "panda_finger_joint2"]


def _rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Axis-angle vector (world frame) of the rotation ``target @ current.T``."""
    r = target @ current.T
    angle = np.arccos(np.clip((np.trace(r) - 1) / 2, -1.0, 1.0))
    if angle < 1e-6:
        return np.zeros(3)
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) / (2 * np.sin(angle))
    return angle * axis


class DrawerExpertPolicy(BatchedPolicy):
    """Reach-pinch-pull with damped least-squares joint deltas.

    Args:
        speed: TCP travel per control step (m).
        closed_width: finger opening (m) below which the fingers count as closed on the handle (the
            nominal bar is 12 mm thick).
        lag: joint delta per unit of joint motion wanted in one control step (the PD's lag).
        pregrasp: distance (m) in front of the grasp point where the straight approach starts.
        full_opening: opening (m) at which it stops pulling.
    """

    def __init__(self, speed: float = 0.005, pregrasp: float = 0.08, full_opening: float = 0.385,
                 lag: float = 6.0, closed_width: float = 0.0135):
        from mani_skill.agents.robots import Panda
        from sapien.wrapper.pinocchio_model import PinocchioModel

        self.speed, self.pregrasp, self.full_opening = float(speed), float(pregrasp), float(full_opening)
        self.lag, self.closed_width = float(lag), float(closed_width)
        self.arm_delta, self.finger_delta, self.grasp_rot, self.approach = ARM_DELTA, FINGER_DELTA, GRASP_ROT, APPROACH
        with open(Panda.urdf_path) as f:
            self.model = PinocchioModel(f.read(), [0.0, 0.0, -9.81])
        self.model.set_joint_order(ARM_JOINTS)
        links = ["panda_link0", *[f"panda_link{i}" for i in range(1, 9)], "panda_hand", "panda_hand_tcp",
                 "panda_leftfinger", "panda_rightfinger"]
        self.model.set_link_order(links)
        self.tcp_index = links.index("panda_hand_tcp")

    def act_one(self, state: np.ndarray) -> np.ndarray:
        q, v, opening = state[:9].astype(np.float64), state[18:21].astype(np.float64), float(state[21])
        self.model.compute_forward_kinematics(q)
        tcp = self.model.get_link_pose(self.tcp_index).to_transformation_matrix()
        width = q[7] + q[8]
        dist = np.linalg.norm(v)
        fingers = 1.0
        if opening >= self.full_opening:
            target, fingers = tcp[:3, 3], -1.0
        elif dist < 0.03 and width < self.closed_width:  # closed on the handle: pull
            target, fingers = tcp[:3, 3] + v + np.array([-2.0 * self.speed, 0.0, 0.0]), -1.0
        elif dist < 0.012 or (dist < 0.03 and width < 0.075):  # at the grasp point (or closing): close
            target, fingers = tcp[:3, 3] + v, -1.0
        elif np.linalg.norm(v - (v @ self.approach) * self.approach) > 0.01 or v @ self.approach < 0.0:
            target = tcp[:3, 3] + v - self.pregrasp * self.approach  # line up before the handle
        else:  # straight in
            target = tcp[:3, 3] + v
        dp = target - tcp[:3, 3]
        n = np.linalg.norm(dp)
        if n > self.speed:
            dp *= self.speed / n
        dw = _rotation_error(self.grasp_rot, tcp[:3, :3])
        dw *= min(1.0, 0.03 / max(np.linalg.norm(dw), 1e-9))
        self.model.compute_full_jacobian(q)
        # Pinocchio's world-frame Jacobian gives the velocity of the point at the world origin:
        # move it to the TCP (v_tcp = v_0 + w x p).
        jac = np.asarray(self.model.get_link_jacobian(self.tcp_index, local=False))[:, :7].copy()
        p = tcp[:3, 3]
        skew = np.array([[0.0, -p[2], p[1]], [p[2], 0.0, -p[0]], [-p[1], p[0], 0.0]])
        jac[:3] -= skew @ jac[3:]
        twist = np.r_[dp, dw]
        dq = jac.T @ np.linalg.solve(jac @ jac.T + 1e-4 * np.eye(6), twist)
        action = np.zeros(9)
        # A delta-from-current PD target moves a joint at stiffness / damping * delta rad/s
        # (1e3 / 1e2 for the Panda): to move dq per control step (1/60 s) the delta is 6 dq.
        arm = dq * self.lag / self.arm_delta
        action[:7] = arm / max(1.0, np.abs(arm).max())  # scaled as a whole: the direction is kept
        action[7:] = fingers
        return action

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = np.asarray(obs["state"], np.float64)
        return np.stack([self.act_one(s) for s in state]).astype(np.float32)
