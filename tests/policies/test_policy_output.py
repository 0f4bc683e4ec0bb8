"""A policy's output the task cannot use (issue 40): a NaN action or one of the wrong shape is a ``sim_error``
naming the policy, never a physical outcome; when every trial on the nominal object ends so, the red-team run
stops in one line and keeps no nominal record (a resume, once the policy is fixed, evaluates it again), and
``grt.evaluate`` says the first reason instead of "success rate nan" and exit code 0.

The trials are :class:`_remote_toy.PointMassSession`'s (a real EpisodeSession on a toy task), run in this
process. The grasp task's two policy kinds are checked in ``tests/tasks/test_grasp.py``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from grt.evaluators.base import NothingScoredError
from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import load_mesh
from grt.journal import Journal
from grt.optimizers import TOPDMOptimizer
from grt.redteam import RedTeamLoop, episode_seeds
from grt.selectors.heuristic import HeuristicSelector

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from _remote_toy import GreedyPolicy, InProcessEvaluator, NaNPolicy, PointMassSession, WrongShapePolicy  # noqa: E402

TASK = {"name": "point_mass", "session": {"_target_": "_remote_toy.PointMassSession"}}


@pytest.fixture(scope="module")
def can():
    return load_mesh("can")


@pytest.mark.parametrize(("policy", "message"), [
    (NaNPolicy(), "policy _remote_toy.NaNPolicy returned a non-finite action [nan, nan]"),
    (WrongShapePolicy(), "policy _remote_toy.WrongShapePolicy returned actions of shape (1, 3); the task takes "
                         "(1, 2): fix the policy's act()")])
def test_unusable_closed_loop_output_is_a_sim_error_naming_the_policy(policy, message, can):
    session = PointMassSession(policy)
    session.load_object(can, [])
    outcome = session.run_trial(3)
    assert outcome.mode == "sim_error" and not outcome.success and outcome.info["steps"] == 0  # the first step
    assert outcome.info["error"] == f"PolicyOutputError: {message}", outcome.info["error"]


def _loop(journal: Path, can, policy: str) -> RedTeamLoop:
    handles = HeuristicSelector(k=4, seed=0).select(can, "")
    evaluator = InProcessEvaluator(TASK, {"_target_": f"_remote_toy.{policy}"})
    return RedTeamLoop(ShapeDeformer(can, handles.handles, handles.anchors),
                       TOPDMOptimizer(len(handles.handles), population=3, sigma=0.02, seed=0), evaluator,
                       Journal(journal), episode_seeds(0, 3), iterations=1)


def test_a_nominal_object_nothing_was_scored_on_stops_the_run_and_is_not_journaled(can, tmp_path):
    """The first reason in the one line; the journal keeps nothing of it, so the resume with the policy fixed
    evaluates the nominal object (a failed nominal record poisoned every resume before)."""
    journal = tmp_path / "journal.jsonl"
    with pytest.raises(NothingScoredError) as err:
        _loop(journal, can, "WrongShapePolicy").run()
    assert "\n" not in str(err.value)
    assert str(err.value).startswith("every trial on the nominal object (3) ended in sim_error, so it has no score; "
                                     "the first (seed "), err.value
    assert "PolicyOutputError: policy _remote_toy.WrongShapePolicy returned actions of shape (1, 3)" in str(err.value)
    assert not journal.exists() or journal.read_text() == ""
    result = _loop(journal, can, "GreedyPolicy").run()  # fixed: the same run goes on
    assert result.s0 == result.s0 and len(Journal(journal)) == 4


def test_an_evaluation_nothing_was_scored_in_is_one_line_with_the_first_reason(tmp_path, capsys, monkeypatch):
    """``grt.evaluate``: "success rate nan" and exit code 0 before; one line, exit code 2, the record kept."""
    from grt.cli._common import exit_on_user_error
    from grt.cli.evaluate import evaluate
    from grt.config import validate
    from tests.runner.conftest import compose_run

    monkeypatch.syspath_prepend(str(HERE))
    cfg = compose_run(["object=can", "budget.trials=2", "~task.session", "+task.session={_target_:_remote_toy."
                       "PointMassSession}", "~policy", "+policy={_target_:_remote_toy.NaNPolicy}",
                       "evaluator._target_=_remote_toy.InProcessEvaluator"], config_name="evaluate")
    with pytest.raises(SystemExit) as info, exit_on_user_error():
        validate(cfg)
        evaluate(cfg, tmp_path)
    err = capsys.readouterr().err
    assert info.value.code == 2 and err.count("\n") == 1, err
    assert err.startswith("error: every trial on the object can (2) ended in sim_error, so it has no score; the "
                          "first (seed "), err
    assert "policy _remote_toy.NaNPolicy returned a non-finite action" in err
    assert err.rstrip().endswith(f"every trial's reason is in {tmp_path / 'evaluation.json'}")
    assert (tmp_path / "evaluation.json").is_file()


def test_a_policy_that_works_is_unchanged(can):
    session = PointMassSession(GreedyPolicy())
    session.load_object(can, [])
    assert {session.run_trial(s).mode for s in range(12)} == {"success", "timeout"}
