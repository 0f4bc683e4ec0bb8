"""What a policy that drives a ManiSkill env itself (``solve(env, seed)``) is given: the session's env with
every step recorded, so the session judges the trial from the steps the policy took
(:class:`grt.tasks.maniskill.session.ManiSkillSession`)."""

from __future__ import annotations

import gymnasium as gym

from grt.tasks.batched import info_at


class StepLimit(Exception):
    """The episode of an env-driving policy is over: it took more steps than the session allows, or its
    simulation failed (the recorder's ``error`` says how)."""


class StepRecorder(gym.Wrapper):
    """The session's env as an env-driving policy sees it: steps pass through, and each step's success and
    failure flags are recorded (``session.info_batch``) and checked (``session.check_batch``: a non-finite
    state or a runaway actor ends the episode).

    Attributes:
        steps: steps taken; success: whether the env reported success at any of them; last: the last
            step's record (``None`` before the first); error: the simulation failure that ended the episode
            (``"Type: message"``), or ``None``.
    """

    def __init__(self, env, session, limit: int):
        super().__init__(env)
        self.session, self.limit = session, int(limit)
        self.steps, self.success, self.last, self.error = 0, False, None, None

    def step(self, action):
        if self.steps >= self.limit:
            raise StepLimit(f"more than {self.limit} steps")
        out = self.env.step(action)
        state = self.session.info_batch(out[4])
        self.error = self.session.check_batch(state)[0]
        if self.error is not None:
            raise StepLimit(self.error)
        self.steps += 1
        self.last = info_at(state, 0)
        self.success |= bool(self.last["success"])
        return out
