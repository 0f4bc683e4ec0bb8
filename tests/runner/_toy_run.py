"""A whole ``python -m grt.run`` without the simulator, for the resume tests (imported by the app).

``TOY`` are the overrides of such a run: the task's session class is the base :class:`TaskSession`'s
(:class:`ToyTaskSession`: only its class-level checks run) and :class:`ToyEvaluator` scores a candidate by its volume, one mesh after the other, each called back (and so
journaled) before the next starts. With the environment variable ``GRT_TEST_INTERRUPT_AT=n`` the n-th mesh
scored raises ``KeyboardInterrupt``, as Ctrl-C would; with ``GRT_TEST_HOLD_FILE=PATH`` every mesh after the
first (the nominal object) waits while PATH exists (at most 120 s): a test holds a run mid-way, with one
journal line, for as long as it needs.

Two other policies, for the confirmation tests (``+evaluator.coin=P``, ``+evaluator.bar_mm=B``): ``coin``, a
policy blind to geometry whose every trial is a fresh coin flip (success with probability ``P``, seeded by
the shape and the episode: any change of the shape re-draws it, as a learned grasp network does); ``bar_mm``,
a policy that fails when the shape moved a vertex farther than ``B`` x (0.5 + a seeded uniform) mm.
"""

from __future__ import annotations

import os
import time

import numpy as np

from grt.evaluators.base import CandidateResult, Evaluator
from grt.geometry.mesh import mesh_hash
from grt.tasks.base import TaskSession, TrialOutcome

TOY = ["task.session._target_=tests.runner._toy_run.ToyTaskSession",
       "evaluator._target_=tests.runner._toy_run.ToyEvaluator"]


class ToyTaskSession(TaskSession):
    """The base session's class-level checks (``check_object``, ``observation_spec``); never built (the toy
    evaluator scores without a simulator). It takes the task's session keys, as a real session does."""

    def __init__(self, **session_kwargs):
        raise NotImplementedError("the toy runs score without a task session")


class ToyEvaluator(Evaluator):
    """Trial ``seed`` succeeds when the candidate keeps more of the nominal volume than a seeded bar."""

    races = True  # evaluate_each runs a candidate in rounds when given race

    def __init__(self, nominal, coin: float | None = None, bar_mm: float | None = None, races: bool = True, **_):
        self.races = races  # ``+evaluator.races=false``: an evaluator that cannot race (a user's, the GPU's)
        self.volume = float(nominal.volume)
        self.nominal = np.asarray(nominal.vertices)
        self.coin, self.bar_mm = coin, bar_mm
        self.calls = self.trials = 0

    def _ok(self, mesh, seed: int) -> bool:
        if self.coin is not None:
            key = int(mesh_hash(mesh.vertices, mesh.faces)[:8], 16)
            return bool(np.random.default_rng([key, seed]).random() < self.coin)
        if self.bar_mm is not None:
            moved_mm = 1000 * float(np.max(np.linalg.norm(np.asarray(mesh.vertices) - self.nominal, axis=1)))
            return moved_mm < self.bar_mm * (0.5 + np.random.default_rng(seed).random())
        kept = float(mesh.volume) / self.volume
        return kept > 0.99 - 0.05 * np.random.default_rng(seed).random()

    def evaluate(self, meshes, seeds):
        return self.evaluate_each(meshes, seeds, lambda i, result: None)

    def evaluate_each(self, meshes, seeds, on_result, race=None):
        """One mesh after the other, each called back before the next starts (as the simulator's evaluator
        calls back a population's candidates while the others run); ``calls`` counts meshes. ``race``: its
        trials in rounds, as :class:`grt.evaluators.sim.SimEvaluator` runs them; ``trials`` counts trials."""
        out = []
        for i, mesh in enumerate(meshes):
            self.calls += 1
            if self.calls == int(os.environ.get("GRT_TEST_INTERRUPT_AT", "0")):
                raise KeyboardInterrupt
            hold, end = os.environ.get("GRT_TEST_HOLD_FILE"), time.monotonic() + 120
            while hold and self.calls > 1 and os.path.exists(hold) and time.monotonic() < end:
                time.sleep(0.05)
            trials, info = [], {}
            for end in [*(race.at if race is not None else ()), len(seeds)]:
                trials += [TrialOutcome(s, float(ok), ok, "success" if ok else "missed")
                           for s in seeds[len(trials):end] for ok in [self._ok(mesh, s)]]
                verdict = race.stop([t.score for t in trials]) if race is not None and end < len(seeds) else None
                if race is not None and (verdict is not None or end == len(seeds)):
                    info["race"] = {"trials": end, "of": len(seeds), **(verdict or {"stopped": None})}
                    break
            self.trials += len(trials)
            out.append(CandidateResult.from_trials(trials, wall_s=0.0, info=info))
            on_result(i, out[-1])
        return out

    def collision_parts(self, mesh):
        return [np.asarray(mesh.convex_hull.vertices)]
