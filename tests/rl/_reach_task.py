"""A tiny but real episodic task for the learning tests (imported by spawned workers too).

A point on a line must reach a seeded goal: ``state = (position, goal - position)``, action in
[-1, 1] moves it by ``0.1 * action``; success within 0.05 of the goal; reward ``-|goal - position|``.
The "object" changes the step size (its x extent), so a shape matters the way geometry does.
"""

from __future__ import annotations

import numpy as np

from grt.tasks.base import EpisodeSession


class ReachSession(EpisodeSession):
    obs_spec = {"state": (2,)}
    num_actions = 1
    task_name = "reach"

    def __init__(self, policy=None, max_steps: int = 20, rebuild_each_trial: bool = False):
        super().__init__(policy, max_steps, rebuild_each_trial)
        self._check_policy()
        self.scale, self.x, self.goal = 0.1, 0.0, 0.0
        self.loads = 0

    def load_object(self, mesh, parts) -> None:
        self.scale = 0.1 * float(np.ptp(np.asarray(mesh.vertices)[:, 0])) / 0.06
        self.loads += 1

    def _reset_env(self, seed: int, rebuild: bool) -> None:
        rng = np.random.default_rng(seed)
        self.x, self.goal = 0.0, float(rng.uniform(-1.0, 1.0))

    def _step_env(self, action: np.ndarray):
        self.x += self.scale * float(action[0])
        err = abs(self.goal - self.x)
        return -err, err < 0.05, {"error": err}

    def observe(self) -> dict[str, np.ndarray]:
        return {"state": np.array([self.x, self.goal - self.x], np.float32)}

    def judge(self, success: bool, info: dict) -> str:
        return "success" if success else "timeout"
