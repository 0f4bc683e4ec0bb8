"""A red-team run of a continuous-score task, without a simulator: loop -> journal -> summary.json.

The evaluator scores a mesh like a drawer task would score it: a per-trial opening in meters that
shrinks as the object swells, plus seeded noise (so trials differ and the interval is not a point).
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from grt import metrics
from grt.config import make_plan
from grt.evaluators.base import CandidateResult, Evaluator
from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import load_mesh
from grt.journal import Journal
from grt.optimizers import TOPDMOptimizer
from grt.outputs import write_outputs
from grt.redteam import RedTeamLoop, episode_seeds
from grt.selectors.heuristic import HeuristicSelector
from grt.tasks.base import TrialOutcome
from tests.runner.conftest import compose_run


class OpeningEvaluator(Evaluator):
    """Opening = 0.35 m x (nominal volume / volume)^8 + N(0, 5 mm) per seed: continuous, in meters."""

    def __init__(self, nominal_volume: float):
        self.nominal_volume = nominal_volume

    def evaluate(self, meshes, seeds):
        out = []
        for m in meshes:
            base = 0.35 * (self.nominal_volume / m.volume) ** 8
            trials = [TrialOutcome(s, float(base + np.random.default_rng(s).normal(0.0, 0.005)), base > 0.3,
                                   "success" if base > 0.3 else "jammed") for s in seeds]
            out.append(CandidateResult.from_trials(trials, wall_s=0.0))
        return out

    def collision_parts(self, mesh):
        return [np.asarray(mesh.convex_hull.vertices)]


@pytest.fixture(scope="module")
def drawer_run(tmp_path_factory):
    """A finished 2-iteration run of a task with ``score: opening``, ``score_unit: m``, ``ci: bootstrap``."""
    run_dir = tmp_path_factory.mktemp("drawer_run")
    cfg = compose_run(["object=can", "task.score=opening", "+task.score_unit=m", "+task.ci=bootstrap",
                       "budget=smoke", "budget.top_k=2", f"paths.output_dir={run_dir}"])
    mesh = load_mesh("can")
    handles = HeuristicSelector(k=4, seed=0).select(mesh, "")
    deformer = ShapeDeformer(mesh, handles.handles, handles.anchors)
    evaluator = OpeningEvaluator(mesh.volume)
    optimizer = TOPDMOptimizer(len(handles.handles), population=3, sigma=0.05, seed=0)
    loop = RedTeamLoop(deformer, optimizer, evaluator, Journal(run_dir / "journal.jsonl"), episode_seeds(0, 6),
                       iterations=2, ci="bootstrap")
    result = loop.run()
    summary = write_outputs(make_plan(cfg), result, deformer, handles, evaluator, wall_s=1.0)
    return run_dir, result, summary


def test_summary_names_the_score_and_uses_the_paper_metrics(drawer_run):
    run_dir, result, summary = drawer_run
    stored = json.loads((run_dir / "summary.json").read_text())
    assert (stored["score_name"], stored["score_unit"], stored["ci"]) == ("opening", "m", "bootstrap")
    assert 0.3 < stored["s0"] < 0.4  # meters, not a success rate
    expected = metrics.summarize(result.s0, result.iteration_scores)
    assert stored["final_drop"] == pytest.approx(expected["final_drop"])
    assert stored["final_drop"] > 0.05  # the search found narrower openings
    assert stored["best_score"] == pytest.approx(min(min(s) for s in result.iteration_scores))
    drop = (stored["s0"] - stored["best_score"]) / stored["s0"]
    assert stored["final_drop"] == pytest.approx(max(0.0, drop))
    assert "note" not in stored
    for name in ("curve.png", "shapes.png"):
        assert (run_dir / name).stat().st_size > 0


def test_crashshapes_are_the_lowest_continuous_scores(drawer_run):
    _, result, summary = drawer_run
    ranked = sorted(s for it in result.iteration_scores for s in it)
    failing = [s for s in ranked if (result.s0 - s) / result.s0 >= summary["crash_margin"]]  # issue 33 §3
    kept = summary["crashshapes"] if failing else summary["best_candidates"]
    assert [c["score"] for c in kept] == pytest.approx((failing or ranked)[:2])


def test_journal_keeps_each_trials_opening_and_the_bootstrap_interval(drawer_run):
    run_dir, result, _ = drawer_run
    records = Journal(run_dir / "journal.jsonl").records  # reloaded from disk
    assert len(records) == 1 + 2 * 3
    for rec, live in zip(records, result.records, strict=True):
        scores = [t["score"] for t in rec["trials"]]
        assert scores == [t["score"] for t in live["trials"]]  # floats survive the round trip exactly
        assert not set(scores) <= {0.0, 1.0}
        assert rec["score"] == pytest.approx(np.mean(scores))
        assert rec["ci95"] == pytest.approx(list(metrics.bootstrap_interval(scores)))


def test_a_run_whose_every_candidate_folds_says_so_and_how_to_fix_it(tmp_path, capsys, caplog):
    """Steps far too large for the object: the validity checks refuse every candidate, nothing is
    simulated; the run warns after the first such iteration, and the summary (file and screen) says why
    the search found nothing and what to change."""
    from grt.geometry.quality import candidate_validity
    from grt.outputs import print_summary
    from grt.runner import FoldingWatch

    cfg = compose_run(["object=can", "task.score=opening", "+task.score_unit=m", "+task.ci=bootstrap",
                       "budget=smoke", "budget.sigma=0.8", f"paths.output_dir={tmp_path}"])
    mesh = load_mesh("can")
    handles = HeuristicSelector(k=6, seed=0).select(mesh, "")
    deformer = ShapeDeformer(mesh, handles.handles, handles.anchors)
    optimizer = TOPDMOptimizer(len(handles.handles), population=3, sigma=0.8, seed=0)
    journal = Journal(tmp_path / "journal.jsonl")
    watch = FoldingWatch(journal, len(handles.handles), 0.8)
    loop = RedTeamLoop(deformer, optimizer, OpeningEvaluator(mesh.volume), journal, episode_seeds(0, 2),
                       iterations=1, ci="bootstrap", validity=candidate_validity, on_iteration=lambda t, _: watch(t))
    with caplog.at_level("WARNING", logger="grt.run"):
        result = loop.run()
    assert "iteration 1: all 3 candidates were implausible" in caplog.text
    summary = write_outputs(make_plan(cfg), result, deformer, handles, OpeningEvaluator(mesh.volume), wall_s=1.0)
    assert summary["invalid_candidates"] == 3 and summary["best_score"] is None
    stored = json.loads((tmp_path / "summary.json").read_text())
    assert "all 3 candidates were implausible" in stored["note"] and "lower budget.sigma" in stored["note"]
    print_summary(summary, tmp_path)
    out = " ".join(capsys.readouterr().out.split())
    assert "implausible: 3 of 3 candidates" in out and "selector=heuristic" in out
    assert stored["validity_checked"] is True

    # the same steps with the checks off: the folded cans are simulated, and nothing claims they were plausible
    unchecked = tmp_path / "unchecked"
    unchecked.mkdir()
    loop = RedTeamLoop(deformer, TOPDMOptimizer(len(handles.handles), population=3, sigma=0.8, seed=0),
                       OpeningEvaluator(mesh.volume), Journal(unchecked / "journal.jsonl"), episode_seeds(0, 2),
                       iterations=1, ci="bootstrap")
    summary = write_outputs(replace(make_plan(cfg), run_dir=unchecked), loop.run(), deformer, handles, OpeningEvaluator(mesh.volume), wall_s=1.0)
    assert summary["validity_checked"] is False and summary["invalid_candidates"] == 0
    assert "implausible" not in summary.get("note", "")  # (it may say that no CrashShape was found)
    print_summary(summary, unchecked)
    assert "plausibility not checked" in " ".join(capsys.readouterr().out.split())
