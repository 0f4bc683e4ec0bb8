"""Bayesian optimization with Optuna's Gaussian-process sampler (``optimizer=optuna_gp``)."""

from __future__ import annotations

import logging
import math

import numpy as np

from grt.optimizers.base import Optimizer


class OptunaGPOptimizer(Optimizer):
    """Optuna's ``GPSampler`` (a Gaussian process with log expected improvement; a population is one batch of
    asks, the candidates still running fantasized) over the ``3H`` displacements in a box of ``bound`` x
    ``sigma`` around ``mu0``. Its first ``n_startup`` candidates are its initial design (uniform random
    draws, seeded; by default the first population); the search needs more candidates than that to be a
    Bayesian one.

    Determinism: the sampler is seeded from ``seed`` and an in-memory study is replayed ask for ask, tell for
    tell, so a resumed run proposes the journal's candidates again (checked by the tests).

    Args:
        num_handles, population, sigma, seed, mu0: see :class:`~grt.optimizers.base.Optimizer`.
        iterations: ``T``; ``population x iterations`` must exceed ``n_startup``.
        n_startup: the initial design's size (``None``: one population; Optuna's own default is 10).
        bound: half the box's side, in ``sigma`` (each coordinate in ``mu0 +- bound * sigma``).
    """

    def __init__(self, num_handles: int, population: int = 10, sigma: float = 0.001, seed: int = 0,
                 mu0: float = 0.0, iterations: int = 10, n_startup: int | None = None, bound: float = 3.0):
        super().__init__(num_handles, population, sigma, seed, mu0)
        if n_startup is not None and (isinstance(n_startup, bool) or float(n_startup) != int(n_startup)):
            raise ValueError(f"optimizer.n_startup={n_startup}: the initial design's size is a whole number of "
                             "candidates (null: one population)")
        n_startup = self.population if n_startup is None else int(n_startup)
        if n_startup < 1 or not 0 < bound < math.inf:
            raise ValueError(f"optimizer.n_startup must be >= 1 and optimizer.bound a finite number > 0 (the box's "
                             f"half side, in sigma), got {n_startup}, {bound}")
        if self.population * int(iterations) <= n_startup:
            raise ValueError(f"budget.population x budget.iterations = {self.population} x {iterations} = "
                             f"{self.population * int(iterations)} candidates, not more than its initial design of "
                             f"{n_startup} random candidates (optimizer.n_startup): no candidate would come from the "
                             f"Gaussian process; give budget.iterations={n_startup // self.population + 1} or more, "
                             "or a smaller optimizer.n_startup")
        import optuna  # only this optimizer needs it (and torch, through it): loaded when one is built

        optuna.logging.set_verbosity(logging.WARNING)
        sampler = optuna.samplers.GPSampler(seed=int(seed), n_startup_trials=int(n_startup),
                                            independent_sampler=optuna.samplers.RandomSampler(seed=int(seed)))
        self.study = optuna.create_study(direction="minimize", sampler=sampler)
        half = float(bound) * self.sigma
        self.space = {f"x{j}": optuna.distributions.FloatDistribution(self.mu0 - half, self.mu0 + half)
                      for j in range(3 * self.num_handles)}
        self._pending: list = []

    def _propose(self) -> np.ndarray:
        self._pending = [self.study.ask(self.space) for _ in range(self.population)]
        return np.array([[t.params[f"x{j}"] for j in range(len(self.space))] for t in self._pending], np.float64)

    def _update(self, thetas: np.ndarray, scores: np.ndarray) -> None:
        # told as asked: the objective is the score of the candidate's Smoothness-Score projection
        for trial, score in zip(self._pending, scores, strict=True):
            self.study.tell(trial, float(score))
        self._pending = []
