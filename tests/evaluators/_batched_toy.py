"""A cheap batched episode task for the tests of the batched protocol and of evaluator=gpu's bookkeeping.

:class:`PointMassBatch` runs ``num_envs`` point-mass episodes at once (numpy, no simulator): sub-scene ``i``
starts at a position drawn from its own seed, scaled by its object's size, and a greedy policy steers it to a
seeded goal; it succeeds within 0.05 of the goal. The object matters (a larger object starts farther away,
more steps, a timeout beyond reach), a seed listed in ``nan_on`` makes its sub-scene's state non-finite (a
``sim_error``), one in ``unreachable`` cannot start (a start error), and a point beyond ``give_up`` ends hopeless.
It has no ManiSkill limit on sub-scenes, so the tests run several per env on the CPU.
"""

from __future__ import annotations

import numpy as np

from grt.policies.base import BatchedPolicy
from grt.tasks.base import COMMON_MODES
from grt.tasks.batched import EpisodeSession


class Greedy(BatchedPolicy):
    """Head for the goal at full speed (``state = (pos, goal)``)."""

    def __init__(self, device: str = "cpu"):
        self.device, self.batches = device, []

    def reset_batch(self, seeds):
        self.batches.append(list(seeds))

    def act(self, obs):
        state = np.asarray(obs["state"], np.float64)
        return np.clip((state[:, 2:] - state[:, :2]) / 0.1, -1.0, 1.0).astype(np.float32)


class PointMassBatch(EpisodeSession):
    task_name = "point_mass"
    obs_spec = {"state": (4,)}
    num_actions = 2
    failure_modes = (*COMMON_MODES, "lost", "timeout")

    def __init__(self, policy=None, max_steps: int = 12, num_envs: int = 1, sim_backend: str = "physx_cpu",
                 render_backend: str = "none", sim_config: dict | None = None, nan_on: tuple = (),
                 unreachable: tuple = (), give_up: float = 2.0, rebuild_each_trial: bool = True):
        super().__init__(policy, max_steps, rebuild_each_trial)
        self.num_envs, self.sim_backend = int(num_envs), sim_backend
        self.nan_on, self.unreachable, self.give_up = set(nan_on), set(unreachable), float(give_up)
        self.scales, self.assignment = np.ones(1), np.zeros(self.num_envs, np.int64)
        self.loads = 0

    @classmethod
    def max_sub_scenes(cls, sim_backend: str):
        return None

    def load_objects(self, objects, assignment) -> None:
        self.scales = np.array([float(np.max(mesh.extents)) / 0.06 for mesh, _ in objects])
        self.assignment = np.asarray(assignment, np.int64)
        self.loads += 1

    def _reset_batch(self, seeds, rebuild: bool) -> None:
        starts = [np.random.default_rng(int(s)).uniform(-0.6, 0.6, 4) for s in seeds]
        scale = self.scales[self.assignment][:, None]
        self.pos = np.stack([s[:2] for s in starts]) * scale
        self.goal = np.stack([s[2:] for s in starts])
        self.seeds = list(seeds)
        self._errors = [f"RuntimeError: seed {s} cannot start" if s in self.unreachable else None for s in seeds]

    def start_errors(self):
        return list(self._errors)

    def _step_batch(self, actions):
        self.pos = self.pos + 0.1 * np.asarray(actions, np.float64)
        for i, s in enumerate(self.seeds):
            if s in self.nan_on and self.steps >= 2:
                self.pos[i] = np.nan
        distance = np.linalg.norm(self.pos - self.goal, axis=1)
        return -distance, distance < 0.05, {"distance": distance, "far": distance > 1.0}

    def observe_batch(self):
        return {"state": np.concatenate([self.pos, self.goal], axis=1).astype(np.float32)}

    def hopeless_batch(self, info):
        return info["distance"] > self.give_up

    def judge(self, success: bool, info: dict) -> str:
        return "success" if success else ("lost" if info["distance"] > self.give_up else "timeout")
