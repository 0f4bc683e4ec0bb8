"""A tiny but real episodic task for the learning tests (imported by spawned workers too).

A point on a line must reach a seeded goal: ``state = (position, goal - position)``, action in
[-1, 1] moves it by ``0.1 * action``; success within 0.05 of the goal; reward ``-|goal - position|``.
The "object" changes the step size (its x extent), so a shape matters the way geometry does.
"""

from __future__ import annotations

import numpy as np

from grt.tasks.batched import EpisodeSession


class ReachSession(EpisodeSession):
    obs_spec = {"state": (2,)}
    num_actions = 1
    task_name = "reach"

    def __init__(self, policy=None, max_steps: int = 20, rebuild_each_trial: bool = False):
        super().__init__(policy, max_steps, rebuild_each_trial)
        self._check_policy()
        self.scale, self.x, self.goal = 0.1, 0.0, 0.0
        self.loads = 0

    def load_objects(self, objects, assignment) -> None:
        self.scale = 0.1 * float(np.ptp(np.asarray(objects[assignment[0]][0].vertices)[:, 0])) / 0.06
        self.loads += 1

    def _reset_batch(self, seeds, rebuild: bool) -> None:
        rng = np.random.default_rng(seeds[0])
        self.x, self.goal = 0.0, float(rng.uniform(-1.0, 1.0))

    def _step_batch(self, actions: np.ndarray):
        self.x += self.scale * float(actions[0, 0])
        err = abs(self.goal - self.x)
        return np.array([-err]), np.array([err < 0.05]), {"distance": np.array([err])}

    def observe_batch(self) -> dict[str, np.ndarray]:
        return {"state": np.array([[self.x, self.goal - self.x]], np.float32)}

    def judge(self, success: bool, info: dict) -> str:
        return "success" if success else "timeout"
