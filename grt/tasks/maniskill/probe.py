"""GRT's scripted push: an episode that needs no policy, for the open-loop fidelity check of a task that has none.

The hand (gripper closed, a blunt pusher; a stick robot as it is) goes above the actor, comes down beside it on
the side facing away from where the hand starts, and pushes through it along the line from its start to the
actor's centre, a quarter of the actor's footprint off that line, so the actor slides *and* turns: a push
exercises what a copy can get wrong (mass, centre of mass, inertia about the vertical, friction, the contact
with table and hand) without grasping, which no script can do for every shape. Then the hand holds still and
the actor comes to rest.

It steps the env in an end-effector delta control mode (``pd_ee_delta_pos`` or ``pd_ee_delta_pose``): the
waypoints are world positions of the hand, reached with a capped proportional step. Every waypoint is computed
from the *stock* actor's pose and size when the episode starts, so the recorded actions are the stock
episode's; :mod:`grt.tasks.maniskill.fidelity` replays them open-loop on the swap.
"""

from __future__ import annotations

import numpy as np

from grt.tasks.base import TaskInputError

#: the control modes the push steps in (the arm's first three actions are a position delta)
CONTROL_MODES = ("pd_ee_delta_pos", "pd_ee_delta_pose")
CLEARANCE_M = 0.04     # between the hand and the actor's footprint before the push
PUSH_M = 0.10          # how far past the actor's centre the hand pushes
FAST, SLOW = 0.02, 0.008   # m per control step: travelling, pushing
HOLD_STEPS = 15
LAG_M = 0.05           # the longest step the hand is asked for (m): how hard it pushes when held back


class ProbeControlError(TaskInputError):
    """The scripted push needs an end-effector delta control mode."""


def check_control_mode(control_mode: str | None) -> None:
    """Refuse a control mode the push cannot step in (one line naming the fix)."""
    if control_mode not in CONTROL_MODES:
        raise ProbeControlError(f"fidelity.actions=push steps the hand in {' or '.join(CONTROL_MODES)}, the task in "
                                f"{control_mode}: add task.session.control_mode=pd_ee_delta_pose, or give "
                                "fidelity.actions=FILE (a .npy of recorded actions, (T, A))")


def _numpy(value) -> np.ndarray:
    return np.asarray(value.detach().cpu().numpy() if hasattr(value, "detach") else value, np.float64)


def _world_points(session) -> np.ndarray:
    """``(V, 3)`` the stock actor's vertices in the world, at its pose now (m)."""
    from grt.tasks.maniskill.swap import _quat_matrix

    pose = _numpy(session.swap.build_of(0).actor.pose.raw_pose).reshape(-1, 7)[0]
    return session.swap.stock_hull(0) @ _quat_matrix(pose[3:]).T + pose[:3]


def waypoints(session) -> list[tuple[np.ndarray, float, int]]:
    """``[(world position (3,), speed m/step, most steps)]`` of the hand for the episode now placed."""
    env = session.unwrapped
    pts = _world_points(session)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2
    tcp = _numpy(env.agent.tcp.pose.p).reshape(-1, 3)[0]
    along = centre[:2] - tcp[:2]
    along = along / max(float(np.linalg.norm(along)), 1e-9)
    side = np.array([-along[1], along[0]])
    reach = float(np.max(np.abs((pts[:, :2] - centre[:2]) @ along)))
    width = float(np.max(np.abs((pts[:, :2] - centre[:2]) @ side)))
    line = centre[:2] + 0.25 * width * side
    mid = max(float(centre[2]), 0.015)
    start = line - along * (reach + CLEARANCE_M)
    end = line + along * PUSH_M
    above = float(hi[2]) + 0.05
    return [(np.array([*start, above]), FAST, 60), (np.array([*start, mid]), FAST, 40),
            (np.array([*end, mid]), SLOW, 60)]


def push(session, seed: int) -> None:
    """Reset ``session`` with ``seed`` and step its env through the push (recorded by whoever wraps ``session.env``).

    Raises:
        ProbeControlError: the env is not in an end-effector delta control mode.
    """
    env = session.unwrapped
    check_control_mode(getattr(env, "control_mode", None))
    session.reset(int(seed), rebuild=True)
    arm = env.agent.controller.controllers["arm"]
    scale = float(np.max(np.abs(_numpy(arm.config.pos_upper)))) if arm.config.normalize_action else 1.0
    base = _numpy(env.agent.robot.pose.raw_pose).reshape(-1, 7)[0]
    from grt.tasks.maniskill.swap import _quat_matrix

    to_root = _quat_matrix(base[3:]).T  # the controller's deltas are in the robot's root frame
    size = session.num_actions

    def act(delta_world: np.ndarray) -> np.ndarray:
        action = np.zeros(size, np.float32)
        action[:3] = np.clip(to_root @ delta_world / scale, -1.0, 1.0)
        if size in (4, 7):  # a gripper: closed, a blunt pusher
            action[-1] = -1.0
        return action[None]

    for target, speed, most in waypoints(session):
        # a virtual target moves to the waypoint at ``speed``; the hand is pulled to it by a step of up to
        # LAG_M, so a heavy or high-friction actor is pushed harder the more it holds the hand back
        virtual = _numpy(env.agent.tcp.pose.p).reshape(-1, 3)[0]
        for _ in range(most):
            tcp = _numpy(env.agent.tcp.pose.p).reshape(-1, 3)[0]
            if np.linalg.norm(target - tcp) < 0.003:
                break
            ahead = target - virtual
            virtual = virtual + ahead * min(1.0, speed / max(float(np.linalg.norm(ahead)), 1e-9))
            gap = virtual - tcp
            session.env.step(act(gap * min(1.0, LAG_M / max(float(np.linalg.norm(gap)), 1e-9))))
    for _ in range(HOLD_STEPS):
        session.env.step(act(np.zeros(3)))
