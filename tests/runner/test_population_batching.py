"""The red-team loop scores a whole population in one evaluator call and journals each candidate as it
finishes, in (iteration, candidate) order whatever the order in which the evaluator finishes them.

The evaluators here score a mesh by its volume (no simulator); the simulator's side (``SimEvaluator``
calling back per mesh while the others still run) is tested in tests/evaluators/test_population.py.
"""

from __future__ import annotations

import json

import numpy as np

from grt.evaluators.base import CandidateResult, Evaluator
from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import load_mesh
from grt.journal import Journal
from grt.optimizers import TOPDMOptimizer
from grt.redteam import RedTeamLoop, episode_seeds
from grt.selectors.heuristic import HeuristicSelector
from grt.tasks.base import TrialOutcome


def _result(mesh, seeds) -> CandidateResult:
    v = float(mesh.volume / 1e-4)
    return CandidateResult.from_trials([TrialOutcome(seed=s, score=v, success=False, mode="missed") for s in seeds],
                                       wall_s=0.0)


class CallCounter(Evaluator):
    """Volume score; records the number of meshes of every call (the base class's ``evaluate_each``)."""

    def __init__(self):
        self.sizes: list[int] = []

    def evaluate(self, meshes, seeds):
        self.sizes.append(len(meshes))
        return [_result(m, seeds) for m in meshes]

    def collision_parts(self, mesh):
        return [np.asarray(mesh.convex_hull.vertices)]


class Reversed(CallCounter):
    """Calls back the last mesh first, as a cluster may finish them; the journal lines it saw written."""

    def __init__(self, journal_path):
        super().__init__()
        self.journal_path, self.lines_seen = journal_path, []

    def evaluate_each(self, meshes, seeds, on_result):
        self.sizes.append(len(meshes))
        results = [_result(m, seeds) for m in meshes]
        for i in reversed(range(len(meshes))):
            self.lines_seen.append(self.journal_path.read_text().count("\n") if self.journal_path.exists() else 0)
            on_result(i, results[i])
        return results


def _loop(tmp_path, evaluator, population=4, iterations=3):
    mesh = load_mesh("can")
    hs = HeuristicSelector(k=4, seed=0).select(mesh, "")
    return RedTeamLoop(ShapeDeformer(mesh, hs.handles, hs.anchors),
                       TOPDMOptimizer(len(hs.handles), population=population, sigma=0.02, seed=0), evaluator,
                       Journal(tmp_path / "journal.jsonl"), episode_seeds(0, 2), iterations=iterations)


def _keys(path):
    return [(r["iteration"], r["candidate"]) for r in map(json.loads, path.read_text().splitlines())]


def test_a_population_is_one_evaluator_call(tmp_path):
    ev = CallCounter()
    result = _loop(tmp_path, ev).run()
    # the nominal object, then one call per iteration with every plausible candidate of it
    assert ev.sizes[0] == 1 and len(ev.sizes) == 4
    assert sum(ev.sizes) == result.evaluations == 1 + 3 * 4
    assert _keys(tmp_path / "journal.jsonl") == [(0, 0)] + [(t, i) for t in (1, 2, 3) for i in range(4)]


def test_candidates_finished_out_of_order_are_journaled_in_order(tmp_path):
    path = tmp_path / "in_order" / "journal.jsonl"
    path.parent.mkdir()
    ev = Reversed(path)
    got = _loop(path.parent, ev).run()
    assert _keys(path) == [(0, 0)] + [(t, i) for t in (1, 2, 3) for i in range(4)]
    # nothing of a population is written before its first candidate is in: the last ones wait for it
    assert ev.lines_seen == [0] + [1 + 4 * t for t in range(3) for _ in range(4)]
    plain = _loop(tmp_path, CallCounter()).run()
    assert got.iteration_scores == plain.iteration_scores and got.best_score == plain.best_score



def test_racing_asked_of_an_evaluator_that_cannot_race_is_said_and_every_trial_runs(tmp_path, caplog):
    from grt.racing import Racing

    mesh = load_mesh("can")
    hs = HeuristicSelector(k=4, seed=0).select(mesh, "")
    loop = RedTeamLoop(ShapeDeformer(mesh, hs.handles, hs.anchors),
                       TOPDMOptimizer(len(hs.handles), population=4, sigma=0.02, seed=0), CallCounter(),
                       Journal(tmp_path / "journal.jsonl"), episode_seeds(0, 2), iterations=1,
                       racing=Racing(2, 0.05, 3, 0.1))  # CallCounter: the base class's evaluate_each
    assert "CallCounter runs every trial of a candidate" in caplog.text and "races nothing" in caplog.text
    loop.run()
    records = [json.loads(line) for line in (tmp_path / "journal.jsonl").read_text().splitlines()]
    assert len(records) == 5 and all(len(r["trials"]) == 2 and "race" not in r for r in records)
