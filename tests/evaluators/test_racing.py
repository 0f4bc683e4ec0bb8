"""Racing in the simulator's evaluator: a candidate's seeds run in rounds, in order; a stopped candidate frees
its workers and its result holds the trials it ran, the same whatever the number of workers.

Real worker processes with the toy session; the rule itself is tests/runner/test_racing_rule.py.
"""

from __future__ import annotations

from dataclasses import dataclass

from grt.evaluators.sim import SimEvaluator


@dataclass
class StopAt:
    """A race that stops every mesh at the look ``when`` (``None``: never): the evaluator's side only."""

    at: tuple = (2, 4)
    when: int | None = 2

    def stop(self, scores, errors=0):
        return {"stopped": "test", "n": len(scores)} if len(scores) + errors == self.when else None


def _modes(trials):
    return [(t.seed, t.mode, t.score) for t in trials]


def test_racing_runs_rounds_in_seed_order_and_a_stopped_mesh_frees_its_workers(toy_configs, toy_reference, u_mesh,
                                                                               u_deformed):
    task, policy = toy_configs()
    seeds = toy_reference["seeds"]
    nominal, deformed = toy_reference["results"]
    got = {}
    for workers in (1, 2):
        with SimEvaluator(task, policy, workers=workers, nominal=u_mesh, progress=False,
                          cache_dir=toy_reference["cache_dir"]) as ev:
            stopped = ev.evaluate([u_mesh, u_deformed, u_mesh], seeds, race=StopAt(when=4))
            assert ev.pool.trials == 3 * 4  # the rounds after a stop never ran
            full = ev.evaluate_each([u_deformed], seeds, lambda i, r: None, race=StopAt(when=None))
        got[workers] = [_modes(r.trials) for r in stopped + full]
        assert [r.info["race"] for r in stopped] == [{"trials": 4, "of": 6, "stopped": "test", "n": 4}] * 3
        assert full[0].info["race"] == {"trials": 6, "of": 6, "stopped": None}
    # the trials a stopped mesh ran are its first seeds' outcomes, as without racing; any number of workers
    assert got[1] == got[2] == [_modes(nominal.trials[:4]), _modes(deformed.trials[:4]), _modes(nominal.trials[:4]),
                                _modes(deformed.trials)]
