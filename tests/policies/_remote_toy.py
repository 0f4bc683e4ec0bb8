"""A cheap closed-loop task and policy for the remote-policy tests (imported by spawned workers and by the
server script ``_serve_toy.py``), and two policies whose output the task cannot use.

:class:`PointMassSession` is a real :class:`grt.tasks.batched.EpisodeSession` (its ``run_trial`` records
failures as the simulator's tasks do): a point starts and aims at seeded positions, each action moves it
by at most 0.1 per axis; it succeeds within 0.05 of the goal before ``max_steps`` (far goals time out).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from grt.evaluators.base import CandidateResult, Evaluator
from grt.policies.base import BatchedPolicy
from grt.tasks.base import COMMON_MODES
from grt.tasks.batched import EpisodeSession


class GreedyPolicy(BatchedPolicy):
    """Head for the goal at full speed; ``delay`` seconds per call (a slow network policy)."""

    def __init__(self, delay: float = 0.0):
        self.delay = float(delay)

    def act(self, obs):
        if self.delay:
            time.sleep(self.delay)
        state = np.asarray(obs["state"], np.float64)
        return np.clip((state[:, 2:] - state[:, :2]) / 0.1, -1.0, 1.0).astype(np.float32)


class NaNPolicy(BatchedPolicy):
    """A policy whose output went wrong: NaN actions (a diverged network)."""

    def act(self, obs):
        return np.full((len(obs["state"]), 2), np.nan, np.float32)


class WrongShapePolicy(BatchedPolicy):
    """A policy made for another task: three actions where the point mass takes two."""

    def act(self, obs):
        return np.zeros((len(obs["state"]), 3), np.float32)


class InProcessEvaluator(Evaluator):
    """The task session of ``task`` with ``policy``, its trials run in this process (what a worker does), for
    the tests of what the apps make of the outcomes (``evaluator._target_=_remote_toy.InProcessEvaluator``)."""

    def __init__(self, task: dict, policy: dict, nominal=None, **_):
        from grt.evaluators.pool import build_session

        self.session, self.collision_s = build_session(task, policy), 0.0

    def evaluate(self, meshes, seeds):
        out = []
        for mesh in meshes:
            self.session.load_object(mesh, [])
            out.append(CandidateResult.from_trials([self.session.run_trial(s) for s in seeds], wall_s=0.0))
        return out

    def collision_parts(self, mesh):
        return [np.asarray(mesh.convex_hull.vertices)]


class PointMassSession(EpisodeSession):
    task_name = "point_mass"
    obs_spec = {"state": (4,)}
    num_actions = 2
    failure_modes = (*COMMON_MODES, "timeout")

    def __init__(self, policy=None, max_steps: int = 8, rebuild_each_trial: bool = True):
        super().__init__(policy, max_steps, rebuild_each_trial)
        self.scale = 1.0

    def load_objects(self, objects, assignment) -> None:
        self.scale = float(np.max(objects[assignment[0]][0].extents)) / 0.06  # the object matters a little

    def _reset_batch(self, seeds, rebuild: bool) -> None:
        rng = np.random.default_rng(seeds[0])
        self.pos, self.goal = rng.uniform(-0.6, 0.6, 2) * self.scale, rng.uniform(-0.6, 0.6, 2)

    def _step_batch(self, actions):
        self.pos = self.pos + 0.1 * np.asarray(actions[0], np.float64)
        distance = np.array([np.linalg.norm(self.pos - self.goal)])
        return -distance, distance < 0.05, {"distance": distance}

    def observe_batch(self):
        return {"state": np.concatenate([self.pos, self.goal]).astype(np.float32)[None]}

    def judge(self, success: bool, info: dict) -> str:
        return "success" if success else "timeout"


if __name__ == "__main__":  # python _remote_toy.py PORT [DELAY]: serve GreedyPolicy (the server of the tests)
    from grt.policy_server import PolicyServer

    policy = GreedyPolicy(float(sys.argv[2]) if len(sys.argv) > 2 else 0.0)
    server = PolicyServer(act=policy.act, kind="batched", task="point_mass", obs={"state": [4]}, action_size=2,
                          name="greedy", version="1", port=int(sys.argv[1]))
    print(server.url, flush=True)
    server.serve_forever()
