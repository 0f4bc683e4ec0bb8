"""An analytic insertion policy: servo the hand to the observed target pose (a baseline, no learning).

It reads the task's 24-D ``state`` (:mod:`grt.tasks.insertion_env`): the displacement from the TCP
to the noisy target position and the target's and the TCP's orientation, and commands a
proportional delta pose, clipped to the action range. Like the learned state policy it never sees
the plug, so a plug that sits differently in the hand makes it miss: a useful reference for what
learning adds. With ``grip=True`` it also reads the ``grip`` observation (the in-hand correction,
:mod:`grt.tasks.insertion_env`) and servos to ``target @ correction``, the hand pose that puts this
plug where the nominal grip puts it: what an in-hand pose estimate buys an analytic controller.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from grt.policies.base import BatchedPolicy


def _quat_conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], -1)


class ServoInsertionPolicy(BatchedPolicy):
    """Proportional servo on the target pose.

    Args:
        gain: action per unit of (position error / 0.01 m) and (rotation error / 0.01 rad).
        rotate: also correct the orientation (else position only).
        grip: correct the target by the observed in-hand pose (the ``grip`` observation).
    """

    def __init__(self, gain: float = 1.0, rotate: bool = True, grip: bool = False):
        self.gain, self.rotate, self.grip = float(gain), bool(rotate), bool(grip)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = np.asarray(obs["state"], np.float64)
        tcp_q, target_q, disp = state[:, 10:14], state[:, 17:21], state[:, 21:24]
        if self.grip:
            grip = np.asarray(obs["grip"], np.float64)
            target = Rotation.from_quat(target_q, scalar_first=True)
            disp = disp + target.apply(grip[:, :3])
            target_q = (target * Rotation.from_rotvec(grip[:, 3:])).as_quat(scalar_first=True)
        action = np.zeros((len(state), 6))
        action[:, :3] = self.gain * disp / 0.01
        if self.rotate:
            # rotation from the TCP to the target, as an axis-angle vector in the world frame
            dq = _quat_mul(target_q, _quat_conj(tcp_q))
            dq *= np.sign(dq[:, :1] + 1e-12)
            angle = 2 * np.arccos(np.clip(dq[:, 0], -1.0, 1.0))
            axis = dq[:, 1:] / np.maximum(np.linalg.norm(dq[:, 1:], axis=1, keepdims=True), 1e-9)
            action[:, 3:] = self.gain * (angle[:, None] * axis) / 0.01
        return np.clip(action, -1.0, 1.0).astype(np.float32)
