"""The evaluator with the real grasp task (ManiSkill CPU simulation): slow, marked sim + slow."""

from __future__ import annotations

import json
import shutil

import pytest
from omegaconf import OmegaConf

from grt.bench.grasp import compose
from grt.evaluators.collision import make_collision
from grt.evaluators.sim import SimEvaluator
from grt.geometry.mesh import load_mesh, mesh_hash
from grt.tasks import get_task

pytestmark = [pytest.mark.sim, pytest.mark.slow]
SEEDS = [1, 2]


@pytest.fixture(scope="module")
def grasp_evaluator(tmp_path_factory):
    """One evaluator (two grasp workers, CoACD per candidate) for the module's tests: a simulator start costs
    more than their trials."""
    cfg = compose(["task=grasp_2cam"])  # two small cameras: the cheapest grasp variant
    task, policy = (OmegaConf.to_container(cfg[k], resolve=True) for k in ("task", "policy"))
    with SimEvaluator(task, policy, workers=2, collision="coacd", cache_dir=str(tmp_path_factory.mktemp("coacd")),
                      progress=False) as ev:
        yield ev


def _trials(result):
    return [(t.seed, t.mode, t.score) for t in result.trials]


def test_same_content_under_a_new_name_scores_the_same(grasp_evaluator, tmp_path):
    # the banana: non-convex (CoACD gives it 3 parts) and decomposed in 1 s, where the mug takes 6 s
    first_path, renamed_path = tmp_path / "banana.ply", tmp_path / "my_renamed_fruit.ply"
    load_mesh("banana").export(first_path)
    shutil.copy(first_path, renamed_path)
    first, renamed = load_mesh(first_path), load_mesh(renamed_path)
    assert mesh_hash(renamed.vertices, renamed.faces) == mesh_hash(first.vertices, first.faces)
    ev = grasp_evaluator
    misses, hits = ev.collision.misses, ev.collision.hits
    a, b = ev.evaluate([first, renamed], SEEDS)
    assert (ev.collision.misses - misses, ev.collision.hits - hits) == (1, 1)  # one CoACD run, found by content
    assert [t.seed for t in a.trials] == SEEDS
    assert all(t.mode in get_task("grasp").failure_modes and t.mode != "sim_error" for t in a.trials), a.trials
    assert a.info["parts"] >= 2
    assert _trials(b) == _trials(a)
    assert [t.info["object_final"] for t in b.trials] == [t.info["object_final"] for t in a.trials]


def test_builtin_object_two_trials_fast_collision(grasp_evaluator):
    """The fast collision path (the nominal decomposition carried to the candidate) in real grasp trials."""
    banana = load_mesh("banana")
    fast = make_collision("fast", banana, None, grasp_evaluator.collision.cache_dir, 64)
    moved = banana.copy()
    moved.vertices = moved.vertices * [1.0, 1.05, 1.0]  # a candidate: the same faces, 5% wider
    (result,) = grasp_evaluator.evaluate([moved], SEEDS, parts=[fast.parts(moved)])
    assert len(result.trials) == 2 and result.sim_errors == 0, result.trials
    assert 0.0 <= result.score <= 1.0 and sum(result.outcomes.values()) == 2


def test_cli_last_line_is_json(grasp_evaluation):
    out, proc = grasp_evaluation  # python -m grt.evaluate object=can task=grasp_2cam budget.trials=2 (conftest.py)
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["trials"] == 2 and sum(summary["outcomes"].values()) == 2
    assert {"success_rate", "ci95", "wall_s", "trials_per_s"} <= summary.keys()
    assert (out / "evaluation.json").is_file()
