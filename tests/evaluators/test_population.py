"""Several meshes in one ``evaluate`` call (a red-team population): each mesh is called back as soon as its
trials are in, while the others still run, and the results are those of the meshes scored alone.

Real worker processes with the toy session (``_toy_session.py``); the red-team loop's side is
tests/runner/test_population_batching.py.
"""

from __future__ import annotations

from grt.evaluators.sim import SimEvaluator
from tests.evaluators._toy_session import stock_box


def _modes(result):
    return [(t.seed, t.mode, t.score) for t in result.trials]


def test_each_mesh_is_called_back_as_its_trials_finish(toy_configs, toy_reference, u_mesh, u_deformed):
    task, policy = toy_configs()
    seeds = toy_reference["seeds"]
    called = []
    # one worker: the jobs run in the order given, so mesh k is whole after exactly (k + 1) x 6 trials
    with SimEvaluator(task, policy, workers=1, nominal=u_mesh, progress=False,
                      cache_dir=toy_reference["cache_dir"]) as ev:
        ev.start(say=None)
        results = ev.evaluate([u_mesh, u_deformed, u_mesh], seeds,
                              on_result=lambda i, r: called.append((i, ev.pool.trials, r)))
        # a candidate None is the task's own stock object (a ManiSkill task's actor: the swap check's reference)
        box = stock_box()
        stock, same = ev.evaluate([None, box], seeds, parts=[None, [box.vertices]])
    assert _modes(stock) == _modes(same) and stock.info["parts"] == 0 and stock.sim_errors == 0
    assert [(i, done) for i, done, _ in called] == [(0, 6), (1, 12), (2, 18)]
    assert all(r is results[i] for i, _, r in called)
    nominal, deformed = toy_reference["results"]
    assert [_modes(r) for r in results] == [_modes(nominal), _modes(deformed), _modes(nominal)]


def test_a_population_on_two_workers_scores_as_each_mesh_alone(toy_configs, toy_reference, u_mesh, u_deformed):
    task, policy = toy_configs()
    seeds = toy_reference["seeds"]
    order = []
    with SimEvaluator(task, policy, workers=2, nominal=u_mesh, progress=False,
                      cache_dir=toy_reference["cache_dir"]) as ev:
        results = ev.evaluate_each([u_deformed, u_mesh], seeds, lambda i, r: order.append(i))
    assert sorted(order) == [0, 1]
    nominal, deformed = toy_reference["results"]
    assert [_modes(r) for r in results] == [_modes(deformed), _modes(nominal)]
    assert all(r.score == ref.score for r, ref in zip(results, (deformed, nominal), strict=True))
