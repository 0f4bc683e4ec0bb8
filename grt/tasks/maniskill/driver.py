"""What a policy that drives a ManiSkill env itself (``solve(env, seed)``) is given: the session's env with
every step recorded, so the session judges the trial from the steps the policy took
(:class:`grt.tasks.maniskill.session.ManiSkillSession`)."""

from __future__ import annotations

import gymnasium as gym


class StepLimit(Exception):
    """An env-driving policy took more steps than the session allows."""


class StepRecorder(gym.Wrapper):
    """The session's env as an env-driving policy sees it: steps pass through, and each step's success and
    failure flags are recorded (``session._info``) and checked (``session._check``: a runaway actor raises).

    Attributes:
        steps: steps taken; success: whether the env reported success at any of them; last: the last
            step's record (``None`` before the first).
    """

    def __init__(self, env, session, limit: int):
        super().__init__(env)
        self.session, self.limit = session, int(limit)
        self.steps, self.success, self.last = 0, False, None

    def step(self, action):
        if self.steps >= self.limit:
            raise StepLimit(f"more than {self.limit} steps")
        out = self.env.step(action)
        info = self.session._info(out[4])
        self.session._check(info)
        self.steps += 1
        self.success |= bool(info["success"])
        self.last = info
        return out
