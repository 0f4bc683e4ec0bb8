"""A resumed run must be the same run: the journal is checked against the config before replay.

The evaluator here scores a mesh by its volume (deterministic, no simulator): these tests are about
the loop's journal/replay logic; the simulator is exercised by test_end_to_end.py.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from grt.evaluators.base import CandidateResult, Evaluator
from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import load_mesh
from grt.journal import Journal, JournalError
from grt.optimizers import TOPDMOptimizer
from grt.redteam import RedTeamLoop, episode_seeds
from grt.selectors.heuristic import HeuristicSelector
from grt.tasks.base import TrialOutcome


class VolumeEvaluator(Evaluator):
    """Score = mesh volume relative to 1e-4 m^3, one identical 'trial' per seed."""

    def __init__(self):
        self.calls = 0

    def evaluate(self, meshes, seeds):
        self.calls += len(meshes)
        out = []
        for m in meshes:
            v = float(m.volume / 1e-4)
            out.append(CandidateResult.from_trials(
                [TrialOutcome(seed=s, score=v, success=False, mode="missed") for s in seeds], wall_s=0.0))
        return out

    def collision_parts(self, mesh):
        return [np.asarray(mesh.convex_hull.vertices)]


def make_loop(tmp_path, obj="can", trials=2, seed=0):
    mesh = load_mesh(obj)
    hs = HeuristicSelector(k=4, seed=0).select(mesh, "")
    deformer = ShapeDeformer(mesh, hs.handles, hs.anchors)
    ev = VolumeEvaluator()
    loop = RedTeamLoop(deformer, TOPDMOptimizer(len(hs.handles), population=3, sigma=0.02, seed=seed), ev,
                       Journal(tmp_path / "journal.jsonl"), episode_seeds(0, trials), iterations=2)
    return loop, ev


def test_replay_evaluates_nothing_again(tmp_path):
    first, _ = make_loop(tmp_path)
    r1 = first.run()
    again, ev = make_loop(tmp_path)
    r2 = again.run()
    assert ev.calls == 0 and r2.iteration_scores == r1.iteration_scores


def test_resume_with_other_seeds_object_or_optimizer_is_refused(tmp_path):
    make_loop(tmp_path)[0].run()
    with pytest.raises(JournalError, match="episode seeds differ"):
        make_loop(tmp_path, trials=3)[0].run()
    with pytest.raises(JournalError, match="parameters differ"):
        make_loop(tmp_path, seed=1)[0].run()


def test_resume_with_another_object_is_refused(tmp_path):
    make_loop(tmp_path)[0].run()
    loop, _ = make_loop(tmp_path, obj="bottle")
    with pytest.raises(JournalError, match="nominal object differs"):
        loop.run()


@pytest.mark.parametrize(("args", "message"), [
    (["resume=/nonexistent/run"], "nothing to resume"),
    (["object=no_such_thing"], "no_such_thing"),
    (["+task.ci=student"], "task.ci='student': use one of auto, wilson, normal, bootstrap"),
])
def test_cli_user_errors_exit_2_with_the_fix(args, message, tmp_path):
    res = subprocess.run([sys.executable, "-m", "grt.run", *args, f"hydra.run.dir={tmp_path}"],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stdout + res.stderr
    assert message in res.stdout + res.stderr
    assert "Traceback" not in res.stdout + res.stderr
