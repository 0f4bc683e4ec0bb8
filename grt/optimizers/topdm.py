"""TOPDM-style selective perturbation: Algorithm 1 of the paper (lines 276-315)."""

from __future__ import annotations

import numpy as np

from grt.optimizers.base import Optimizer, num_elites


class TOPDMOptimizer(Optimizer):
    """Algorithm 1 as written.

    The population starts as ``N`` draws from ``N(mu0, Sigma0)``. Every iteration each candidate gets
    Gaussian noise on ``floor(gamma * H)`` randomly chosen handles (rows of theta), the population is
    evaluated, the ``ceil(rho * N)`` lowest-scoring candidates are kept and replicated (cyclically,
    best first) to refill the population. The best candidate over all iterations is ``best_theta``.

    Args:
        num_handles, population, sigma, seed, mu0: see :class:`~grt.optimizers.base.Optimizer`.
        gamma: fraction of handles perturbed per candidate and iteration (paper: 0.5); at least one.
        elite_frac: ``rho``, fraction of the population kept as elites.
    """

    def __init__(self, num_handles: int, population: int = 10, sigma: float = 0.001, seed: int = 0,
                 mu0: float = 0.0, gamma: float = 0.5, elite_frac: float = 0.2):
        super().__init__(num_handles, population, sigma, seed, mu0)
        if not 0 < gamma <= 1:
            raise ValueError(f"gamma must be in (0, 1], got {gamma}")
        self.gamma = float(gamma)
        self.n_elites = num_elites(self.population, elite_frac)
        self.theta = self.gaussian(*self.shape)  # the initial population, N(mu0, Sigma0)
        self.last_perturbed: np.ndarray | None = None  # (N, k) handle indices of the last ask()

    @property
    def num_perturbed(self) -> int:
        """``floor(gamma * H)`` handles perturbed per candidate (at least one)."""
        return max(1, int(np.floor(self.gamma * self.num_handles + 1e-9)))

    def _propose(self) -> np.ndarray:
        k = self.num_perturbed
        chosen = np.stack([self.rng.choice(self.num_handles, size=k, replace=False)
                           for _ in range(self.population)])
        out = self.theta.copy()
        rows = np.arange(self.population)[:, None]
        out[rows, chosen] += self.gaussian(self.population, k, 3)
        self.last_perturbed = chosen
        return out

    def _update(self, thetas: np.ndarray, scores: np.ndarray) -> None:
        elites = np.argsort(scores, kind="stable")[: self.n_elites]
        self.theta = thetas[elites[np.arange(self.population) % self.n_elites]].copy()
