"""Analytic (scripted, closed-loop) policies for ManiSkill's stock cube tasks, on the env's own state.

They read ManiSkill's flattened ``state`` observation (``obs_mode=state``: ``agent.qpos (9)``,
``agent.qvel (9)``, then the task's ``_get_obs_extra`` in order) and command the Panda's
``pd_ee_delta_pos`` action ``(4,)``: the TCP's displacement target (1 = 0.1 m) and the gripper (1 open,
-1 closed). Each step they look at where the cube, the goal and the hand are now, so a cube that moved
or turned is followed (no plan is replayed). Like GRT's ``insertion_servo``, they assume the nominal
cube's size (``half_size``): a deformed object is their blind spot, which is what red-teaming measures.

- :class:`PushToGoalPolicy` (PushCube-v1, PullCube-v1): go to the side of the cube away from the goal
  (over the cube when it is in the way), come down, and push it along the cube-to-goal line, correcting
  the line as the cube turns; hold still once the cube's centre is over the goal.
- :class:`PickCubePolicy` (PickCube-v1): above the cube, open, down, close, lift to the goal, hold.
- :class:`StackCubePolicy` (StackCube-v1): pick cubeA as above, carry it over cubeB, set it down on it,
  open and move up.
"""

from __future__ import annotations

import numpy as np

from grt.errors import UserError
from grt.policies.base import BatchedPolicy

#: ``obs_mode=state`` layouts (index of the first element): the TCP position, the goal position, the cube's
#: position (the Panda, ``pd_ee_delta_pos``).
LAYOUTS = {
    "push": {"size": 35, "tcp": 18, "goal": 25, "cube": 28},   # PushCube-v1, PullCube-v1
    "pick": {"size": 42, "tcp": 19, "goal": 26, "cube": 29, "grasped": 18},  # PickCube-v1
    "stack": {"size": 48, "tcp": 18, "cube": 25, "goal": 32, "fingers": 7},  # StackCube-v1 (goal: cubeB)
}
STEP_M = 0.1  # meters per unit of pd_ee_delta_pos's position action


class StateLayoutError(UserError):
    """A task whose state or action is not the layout an expert reads."""


class _StateExpert(BatchedPolicy):
    layout: str = "push"
    num_actions = 4

    def __init__(self, half_size: float = 0.02, speed: float = 0.3, gain: float = 1.0):
        self.half, self.speed, self.gain = float(half_size), float(speed), float(gain)
        self.obs_spec = {"state": (LAYOUTS[self.layout]["size"],)}

    def check(self, task: str, obs_spec: dict, num_actions: int) -> None:
        """Refuse an env whose state or action is not the layout this policy reads (one line naming both)."""
        have = tuple(obs_spec.get("state", ())) or None
        if have != self.obs_spec["state"] or int(num_actions) != self.num_actions:
            raise StateLayoutError(f"{type(self).__name__} reads a state of shape {self.obs_spec['state']} and writes "
                                 f"{self.num_actions} actions (the Panda's pd_ee_delta_pos), but task={task} gives "
                                 f"a state of shape {have} and takes {num_actions} actions")

    def _part(self, state: np.ndarray, key: str, n: int = 3) -> np.ndarray:
        i = LAYOUTS[self.layout][key]
        return state[:, i:i + n]

    def _move(self, tcp: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Position actions ``(N, 3)`` towards ``target``, at most ``speed`` (action units) per axis."""
        return np.clip(self.gain * (target - tcp) / STEP_M, -self.speed, self.speed)


class PushToGoalPolicy(_StateExpert):
    """Push (PushCube) or pull (PullCube) the cube to the goal disc; see the module docstring.

    Args:
        half_size: the cube's half size it assumes (m).
        speed: largest position action per axis (0.3: 3 cm per control step).
        gain: fraction of the position error commanded per step.
        clearance: m kept between the hand and the cube's face before pushing.
        travel_z: height (m) of the hand's centre while it goes round (over) the cube.
        push_z: height (m) of the hand's centre while pushing (the cube's centre).
    """

    layout = "push"

    def __init__(self, half_size: float = 0.02, speed: float = 0.3, gain: float = 1.0, clearance: float = 0.02,
                 travel_z: float = 0.08, push_z: float = 0.02):
        super().__init__(half_size, speed, gain)
        self.clearance, self.travel_z, self.push_z = float(clearance), float(travel_z), float(push_z)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = np.asarray(obs["state"], np.float64)
        tcp, goal, cube = self._part(state, "tcp"), self._part(state, "goal"), self._part(state, "cube")
        out = np.zeros((len(state), 4))
        out[:, 3] = -1.0  # closed fingers push as one block
        for k in range(len(state)):
            out[k, :3] = self._push(tcp[k], goal[k], cube[k])
        return out.astype(np.float32)

    def _push(self, tcp: np.ndarray, goal: np.ndarray, cube: np.ndarray) -> np.ndarray:
        line = goal[:2] - cube[:2]
        dist = float(np.linalg.norm(line))
        if dist < 0.005:
            return np.zeros(3)  # there: hold still
        d = line / dist
        rel = tcp[:2] - cube[:2]
        along, lateral = float(rel @ d), float(rel @ np.array([-d[1], d[0]]))
        behind = self.half + self.clearance
        in_line = abs(lateral) < 0.01 and along < -(self.half + 0.005)
        if in_line and tcp[2] < self.push_z + 0.015:  # push: the hand's target is where it leaves the cube at the goal
            target_xy = goal[:2] - d * (self.half + 0.008) + np.array([-d[1], d[0]]) * 0.0
            target_xy = target_xy - np.array([-d[1], d[0]]) * lateral  # and back onto the line
            return self._move(tcp, np.r_[target_xy, self.push_z])
        start = cube[:2] - d * behind
        if in_line or np.linalg.norm(tcp[:2] - start) < 0.01:
            return self._move(tcp, np.r_[start, self.push_z])  # come down behind the cube
        if tcp[2] < self.travel_z - 0.01 and np.linalg.norm(rel) < behind + 0.03:
            return self._move(tcp, np.r_[tcp[:2], self.travel_z])  # near the cube: up first
        return self._move(tcp, np.r_[start, self.travel_z])


class PickCubePolicy(_StateExpert):
    """Pick the cube and hold it at the goal (PickCube-v1); see the module docstring.

    Args:
        half_size: the cube's half size it assumes (m).
        speed, gain: as :class:`PushToGoalPolicy`.
        grasp_depth: how far (m) below the cube's centre... 0: the hand's centre at the cube's centre.
        close_steps: control steps the fingers get to close before the lift.
    """

    layout = "pick"

    def __init__(self, half_size: float = 0.02, speed: float = 0.3, gain: float = 1.0, grasp_depth: float = 0.0,
                 close_steps: int = 4):
        super().__init__(half_size, speed, gain)
        self.grasp_depth, self.close_steps = float(grasp_depth), int(close_steps)
        self._closing: np.ndarray | None = None

    def reset(self, seed: int) -> None:
        self._closing = None

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = np.asarray(obs["state"], np.float64)
        n = len(state)
        if self._closing is None or len(self._closing) != n:
            self._closing = np.zeros(n, int)
        tcp, goal, cube = self._part(state, "tcp"), self._part(state, "goal"), self._part(state, "cube")
        grasped = self._part(state, "grasped", 1)[:, 0] > 0.5
        out = np.zeros((n, 4))
        for k in range(n):
            out[k] = self._pick(k, tcp[k], goal[k], cube[k], bool(grasped[k]))
        return out.astype(np.float32)

    def _pick(self, k: int, tcp, goal, cube, grasped: bool) -> np.ndarray:
        grip = cube + np.array([0.0, 0.0, -self.grasp_depth])
        if grasped or self._closing[k] >= self.close_steps:
            self._closing[k] = self.close_steps if grasped else self._closing[k]
            if not grasped and np.linalg.norm(tcp - grip) > 0.02:  # lost it: open and start again
                self._closing[k] = 0
                return np.r_[self._move(tcp, grip + [0, 0, 0.05]), 1.0]
            return np.r_[self._move(tcp, goal + (tcp - cube)), -1.0]
        if np.linalg.norm(tcp[:2] - grip[:2]) > 0.01 and tcp[2] < grip[2] + 0.03:
            self._closing[k] = 0
            return np.r_[self._move(tcp, np.r_[tcp[:2], grip[2] + 0.05]), 1.0]  # up, out of the cube's way
        if np.linalg.norm(tcp[:2] - grip[:2]) > 0.01:
            return np.r_[self._move(tcp, grip + [0, 0, 0.05]), 1.0]  # above the cube
        if np.linalg.norm(tcp - grip) > 0.006 and self._closing[k] == 0:
            return np.r_[self._move(tcp, grip), 1.0]  # down, open
        self._closing[k] += 1
        return np.r_[np.zeros(3), -1.0]  # close


class StackCubePolicy(PickCubePolicy):
    """Stack cubeA on cubeB (StackCube-v1): :class:`PickCubePolicy` with cubeB's top as the goal; the
    hand opens once cubeA is over cubeB at the stacking height and moves up. The state has no
    ``is_grasped``: a cube is held when the closed fingers stay apart by about its width (qpos 7-8)."""

    layout = "stack"

    def reset(self, seed: int) -> None:
        super().reset(seed)
        self._released = None

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = np.asarray(obs["state"], np.float64)
        n = len(state)
        if self._closing is None or len(self._closing) != n:
            self._closing = np.zeros(n, int)
        if getattr(self, "_released", None) is None or len(self._released) != n:
            self._released = np.zeros(n, bool)
        tcp, cube_b, cube = self._part(state, "tcp"), self._part(state, "goal"), self._part(state, "cube")
        width = self._part(state, "fingers", 2).sum(axis=1)
        out = np.zeros((n, 4))
        for k in range(n):
            held = self._closing[k] >= self.close_steps and width[k] > self.half and np.linalg.norm(tcp[k] - cube[k]) < 0.02
            place = cube_b[k] + [0.0, 0.0, 2 * self.half + 0.003]
            if self._released[k] or (held and np.linalg.norm(cube[k] - place) < 0.006):
                self._released[k] = True
                out[k] = np.r_[self._move(tcp[k], np.r_[tcp[k][:2], place[2] + 0.08]), 1.0]  # open, up
                continue
            over = place + [0.0, 0.0, 0.03] if np.linalg.norm(cube[k][:2] - place[:2]) > 0.006 else place
            out[k] = self._pick(k, tcp[k], over, cube[k], bool(held))
        return out.astype(np.float32)
