"""Optimizers on a cheap analytic objective (the simulator is tested elsewhere)."""

from __future__ import annotations

import numpy as np
import pytest

from grt.optimizers import (
    CEMOptimizer,
    CMAESOptimizer,
    GaussianOptimizer,
    TOPDMOptimizer,
    project_to_budget,
    smoothness_score,
)

ALL = [TOPDMOptimizer, GaussianOptimizer, CEMOptimizer, CMAESOptimizer]
TARGET = np.linspace(-0.05, 0.05, 24).reshape(8, 3)


def objective(thetas):
    """A smooth score to minimize, like a success rate falling as the shape nears TARGET."""
    return np.exp(-np.sum((thetas - TARGET) ** 2, axis=(1, 2)) / 0.01) * -1 + 1


def run_search(cls, seed, iterations=15, population=10):
    opt = cls(8, population=population, sigma=0.02, seed=seed)
    for _ in range(iterations):
        th = opt.ask()
        opt.tell(th, objective(th))
    return opt.best_score


def random_search(seed, evals):
    rng = np.random.default_rng(seed)
    th = 0.02 * rng.standard_normal((evals, 8, 3))
    return objective(th).min()


@pytest.mark.parametrize("cls", [TOPDMOptimizer, CEMOptimizer, CMAESOptimizer])
def test_improves_on_random_search_at_equal_budget(cls):
    ours = np.mean([run_search(cls, s) for s in range(8)])
    rand = np.mean([random_search(100 + s, 150) for s in range(8)])
    assert ours < rand - 0.02, (ours, rand)


def test_gaussian_baseline_is_an_unselected_random_walk():
    opt = GaussianOptimizer(6, population=50, sigma=0.01, seed=0)
    spreads = []
    for _ in range(9):
        th = opt.ask()
        opt.tell(th, np.random.default_rng(0).random(50))  # scores do not steer it
        assert np.array_equal(opt.theta, th)
        spreads.append(th.std())
    # every handle moves each step: the spread grows like sqrt(t) (here t = 2 -> 10 draws)
    assert spreads[-1] / spreads[0] == pytest.approx(np.sqrt(10 / 2), rel=0.15)


def test_topdm_perturbs_exactly_floor_gamma_m_handles():
    opt = TOPDMOptimizer(7, population=6, sigma=0.01, seed=1, gamma=0.5)
    before = opt.theta.copy()
    th = opt.ask()
    changed = np.any(th != before, axis=2)  # (N, H)
    assert opt.num_perturbed == 3
    assert np.all(changed.sum(1) == 3)
    assert np.array_equal(np.sort(opt.last_perturbed, 1), np.sort(np.argwhere(changed)[:, 1].reshape(6, 3), 1))


def test_topdm_elites_replicate():
    opt = TOPDMOptimizer(4, population=10, sigma=0.01, seed=0, elite_frac=0.2)
    th = opt.ask()
    scores = np.arange(10, dtype=float)[::-1]  # candidates 9 and 8 are the elites
    opt.tell(th, scores)
    assert opt.n_elites == 2
    for i in range(10):
        assert np.array_equal(opt.theta[i], th[9] if i % 2 == 0 else th[8])
    assert opt.best_score == 0.0 and np.array_equal(opt.best_theta, th[9])


@pytest.mark.parametrize("cls", ALL)
def test_deterministic_given_seed_and_replayable(cls):
    a, b = cls(5, population=4, sigma=0.01, seed=3), cls(5, population=4, sigma=0.01, seed=3)
    for _ in range(3):
        ta, tb = a.ask(), b.ask()
        assert np.array_equal(ta, tb)
        s = objective(np.pad(ta, ((0, 0), (0, 3), (0, 0))))
        a.tell(ta, s)
        b.tell(tb, s)


def test_ask_tell_protocol_errors():
    opt = TOPDMOptimizer(3, population=2, sigma=0.01)
    with pytest.raises(RuntimeError):
        opt.tell(np.zeros((2, 3, 3)), np.zeros(2))
    opt.ask()
    with pytest.raises(RuntimeError):
        opt.ask()
    with pytest.raises(ValueError, match="finite"):
        opt.tell(np.zeros((2, 3, 3)), np.array([0.0, np.nan]))
    with pytest.raises(ValueError, match="sigma"):
        TOPDMOptimizer(3, sigma=0)


def test_smoothness_projection_bounds_and_keeps_direction(rng):
    thetas = rng.normal(size=(20, 6, 3)) * 0.05
    scale = 0.12  # meters per unit-cube unit
    tau = 0.002
    proj = project_to_budget(thetas, tau, scale)
    ss = smoothness_score(proj, scale)
    assert np.all(ss <= tau + 1e-12)
    over = smoothness_score(thetas, scale) > tau
    assert np.allclose(ss[over], tau)
    for a, b in zip(thetas, proj, strict=True):  # same direction: a positive multiple
        k = np.sum(a * b) / np.sum(a * a)
        assert k > 0 and np.allclose(b, k * a)
    small = thetas * 1e-4
    assert np.array_equal(project_to_budget(small, tau, scale), small)
    assert np.array_equal(project_to_budget(thetas, None, scale), thetas)
    with pytest.raises(ValueError, match="tau"):
        project_to_budget(thetas, -1.0, scale)
