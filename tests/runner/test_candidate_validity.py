"""Implausible candidates (self-intersecting, folded) are journaled, never simulated, never CrashShapes."""

from __future__ import annotations

import math

from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import load_mesh
from grt.geometry.quality import candidate_validity
from grt.journal import Journal
from grt.optimizers import TOPDMOptimizer
from grt.outputs import crash_records
from grt.redteam import RedTeamLoop, episode_seeds
from grt.selectors.heuristic import HeuristicSelector
from tests.runner.test_resume_checks import VolumeEvaluator


def _loop(tmp_path):
    mesh = load_mesh("mug")
    hs = HeuristicSelector(k=8, seed=0).select(mesh, "")
    deformer = ShapeDeformer(mesh, hs.handles, hs.anchors, method="exact")
    ev = VolumeEvaluator()
    # sigma 0.04: point handles push the mug's thin wall through itself in some candidates
    loop = RedTeamLoop(deformer, TOPDMOptimizer(len(hs.handles), population=6, sigma=0.04, seed=0), ev,
                       Journal(tmp_path / "journal.jsonl"), episode_seeds(0, 2), iterations=2,
                       validity=candidate_validity)
    return loop, ev


def test_invalid_candidates_are_recorded_not_simulated(tmp_path):
    loop, ev = _loop(tmp_path)
    result = loop.run()
    explored = [r for r in result.records if r["iteration"] >= 1]
    invalid = [r for r in explored if not r["valid"]]
    assert invalid and len(invalid) < len(explored)
    assert all(r["self_intersections"] > 0 or r["inverted_faces"] > 0 for r in invalid)
    assert all(math.isnan(r["score"]) and r["trials"] == [] for r in invalid)
    assert ev.calls == 1 + len(explored) - len(invalid)  # the nominal + the valid ones
    assert all(r["valid"] for r in crash_records(result.records, 100))
    again, ev2 = _loop(tmp_path)  # a resume replays them without simulating anything
    replayed = again.run()
    assert ev2.calls == 0
    assert [[round(s, 9) if s == s else None for s in it] for it in replayed.iteration_scores] == \
        [[round(s, 9) if s == s else None for s in it] for it in result.iteration_scores]
