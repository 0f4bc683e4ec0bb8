"""Cross-entropy method over handle displacements."""

from __future__ import annotations

import numpy as np

from grt.optimizers.base import Optimizer, num_elites


class CEMOptimizer(Optimizer):
    """Diagonal-Gaussian CEM: sample, keep the lowest-scoring elites, refit mean and std (smoothed).

    Args:
        num_handles, population, sigma, seed, mu0: see :class:`~grt.optimizers.base.Optimizer`.
        elite_frac: fraction of the population used to refit.
        smoothing: weight of the new fit (``alpha``; 1 = no memory).
        min_std_frac: floor on the std as a fraction of ``sigma``, against premature collapse.
    """

    def __init__(self, num_handles: int, population: int = 10, sigma: float = 0.001, seed: int = 0,
                 mu0: float = 0.0, elite_frac: float = 0.3, smoothing: float = 0.7,
                 min_std_frac: float = 0.1):
        super().__init__(num_handles, population, sigma, seed, mu0)
        self.n_elites = num_elites(self.population, elite_frac)
        self.smoothing, self.min_std = float(smoothing), float(min_std_frac) * self.sigma
        self.mean = np.full((self.num_handles, 3), self.mu0)
        self.std = np.full((self.num_handles, 3), self.sigma)

    def _propose(self) -> np.ndarray:
        return self.mean + self.std * self.rng.standard_normal(self.shape)

    def _update(self, thetas: np.ndarray, scores: np.ndarray) -> None:
        elite = thetas[np.argsort(scores, kind="stable")[: self.n_elites]]
        a = self.smoothing
        self.mean = a * elite.mean(0) + (1 - a) * self.mean
        self.std = np.maximum(a * elite.std(0) + (1 - a) * self.std, self.min_std)
