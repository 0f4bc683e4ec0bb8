"""The worker pool with a real (cheap) task session: determinism, crashes, exceptions."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from grt.evaluators.sim import SimEvaluator

SEEDS = [11, 12, 13, 14, 15, 16]


def _evaluate(task, policy, meshes, workers, cache_dir, **kwargs):
    with SimEvaluator(task, policy, workers=workers, collision="fast", nominal=meshes[0], progress=False,
                      cache_dir=str(cache_dir), **kwargs) as ev:
        return ev.evaluate(meshes, SEEDS)


def _modes(results):
    return [[(t.seed, t.mode, t.score) for t in r.trials] for r in results]


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("coacd")


@pytest.fixture(scope="module")
def reference(toy_configs, u_mesh, u_deformed, cache_dir):
    """Outcomes of a healthy session with one worker on [nominal, deformed]."""
    task, policy = toy_configs()
    return _evaluate(task, policy, [u_mesh, u_deformed], 1, cache_dir)


def test_same_results_with_one_or_two_workers(toy_configs, u_mesh, u_deformed, reference, cache_dir):
    task, policy = toy_configs()
    two = _evaluate(task, policy, [u_mesh, u_deformed], 2, cache_dir, chunk_size=2)
    assert _modes(two) == _modes(reference)
    assert [r.score for r in two] == [r.score for r in reference]
    assert [t.seed for t in two[0].trials] == SEEDS
    assert len({t.mode for r in reference for t in r.trials}) == 2  # the toy task does discriminate
    assert all(r.wall_s > 0 and r.info["parts"] >= 2 for r in reference)


def test_exception_in_a_trial_is_a_sim_error(toy_configs, u_mesh, cache_dir):
    task, policy = toy_configs(raise_on=13)
    (result,) = _evaluate(task, policy, [u_mesh], 2, cache_dir)
    bad = result.trials[SEEDS.index(13)]
    assert bad.mode == "sim_error" and "physics exploded on seed 13" in bad.info["error"]
    assert result.outcomes.get("sim_error") == 1
    assert len(result.valid_trials) == len(SEEDS) - 1


def test_a_worker_that_always_dies_is_restarted_then_gives_up(toy_configs, u_mesh, reference, cache_dir):
    task, policy = toy_configs(crash_on=12)
    (result,) = _evaluate(task, policy, [u_mesh], 2, cache_dir, max_retries=1)
    bad = result.trials[SEEDS.index(12)]
    assert bad.mode == "sim_error" and "exit code 3" in bad.info["error"] and "2 times" in bad.info["error"]
    # Every other seed still ran, with the outcome a healthy worker gives.
    for got, want in zip(result.trials, reference[0].trials, strict=True):
        if got.seed != 12:
            assert (got.mode, got.score) == (want.mode, want.score)


def test_a_transient_crash_is_rerun(toy_configs, u_mesh, reference, cache_dir, tmp_path):
    task, policy = toy_configs(crash_on=14, crash_once_marker=str(tmp_path / "crashed"))
    with SimEvaluator(task, policy, workers=1, nominal=u_mesh, progress=False, cache_dir=str(cache_dir)) as ev:
        (result,) = ev.evaluate([u_mesh], SEEDS)
        assert ev.pool.restarts == 1
    assert (tmp_path / "crashed").exists()
    assert _modes([result]) == _modes(reference[:1])


def test_a_session_that_cannot_be_built_is_a_clear_error(toy_configs, u_mesh, cache_dir):
    task, policy = toy_configs(fail_build=True)
    with pytest.raises(RuntimeError, match="toy session refuses to build"):
        _evaluate(task, policy, [u_mesh], 1, cache_dir)


def test_render_writes_one_picture_per_trial(toy_configs, u_mesh, cache_dir, tmp_path):
    task, policy = toy_configs()
    _evaluate(task, policy, [u_mesh], 1, cache_dir, render_dir=str(tmp_path / "renders"))
    pictures = sorted(p.name for p in (tmp_path / "renders").iterdir())
    assert pictures == sorted(f"candidate000_seed{s}.png" for s in SEEDS)


def test_configs_must_be_plain_dicts(u_mesh):
    with pytest.raises(ValueError, match="plain dict"):
        SimEvaluator(OmegaConf.create({"session": {}}), {}, nominal=u_mesh)


def test_the_workers_swap_in_another_policy_for_one_call_and_give_their_own_back(toy_configs, u_mesh, reference,
                                                                                  cache_dir):
    task, policy = toy_configs()
    strict = {**policy, "fill": 0.99}  # no seed fills its bar: every trial fails under this policy
    with SimEvaluator(task, policy, workers=2, collision="fast", nominal=u_mesh, progress=False,
                      cache_dir=str(cache_dir)) as ev:
        (swapped,) = ev.evaluate([u_mesh], SEEDS, policy=strict)
        (again,) = ev.evaluate([u_mesh], SEEDS, policy=strict)
        (own,) = ev.evaluate([u_mesh], SEEDS)  # no policy given: the pool's own, on the same workers
        (broken,) = ev.evaluate([u_mesh], SEEDS, policy={**policy, "_target_": "no.such.Policy"})
    assert reference[0].score > 0 and swapped.score == again.score == 0.0
    assert _modes([own]) == _modes(reference[:1])
    assert all(t.mode == "sim_error" and "policy failed" in t.info["error"] for t in broken.trials)
