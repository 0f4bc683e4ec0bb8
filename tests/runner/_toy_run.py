"""A whole ``python -m grt.run`` without the simulator, for the resume tests (imported by the app).

``TOY`` are the overrides of such a run: the task's session class is the base :class:`TaskSession` (only its
class-level checks run) and :class:`ToyEvaluator` scores a candidate by its volume. With the environment
variable ``GRT_TEST_INTERRUPT_AT=n`` the n-th ``evaluate`` call raises ``KeyboardInterrupt``, as Ctrl-C would.
"""

from __future__ import annotations

import os

import numpy as np

from grt.evaluators.base import CandidateResult, Evaluator
from grt.tasks.base import TrialOutcome

TOY = ["task.session._target_=grt.tasks.base.TaskSession",
       "evaluator._target_=tests.runner._toy_run.ToyEvaluator"]


class ToyEvaluator(Evaluator):
    """Trial ``seed`` succeeds when the candidate keeps more of the nominal volume than a seeded bar."""

    def __init__(self, nominal, **_):
        self.volume = float(nominal.volume)
        self.calls = 0

    def evaluate(self, meshes, seeds):
        self.calls += 1
        if self.calls == int(os.environ.get("GRT_TEST_INTERRUPT_AT", "0")):
            raise KeyboardInterrupt
        out = []
        for mesh in meshes:
            kept = float(mesh.volume) / self.volume
            trials = [TrialOutcome(s, float(ok), ok, "success" if ok else "missed")
                      for s in seeds for ok in [kept > 0.99 - 0.05 * np.random.default_rng(s).random()]]
            out.append(CandidateResult.from_trials(trials, wall_s=0.0))
        return out

    def collision_parts(self, mesh):
        return [np.asarray(mesh.convex_hull.vertices)]
