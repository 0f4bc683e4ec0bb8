"""Gaussian perturbation: the paper's unstructured baseline (Table 2)."""

from __future__ import annotations

from grt.optimizers.base import Optimizer


class GaussianOptimizer(Optimizer):
    """Every candidate random-walks: all handles get ``N(mu0, Sigma0)`` noise every iteration.

    No selection and no selective perturbation, so it isolates what TOPDM's structure adds: the same
    noise scale and evaluation budget, only the best candidate seen is remembered.
    """

    def __init__(self, num_handles: int, population: int = 10, sigma: float = 0.001, seed: int = 0,
                 mu0: float = 0.0):
        super().__init__(num_handles, population, sigma, seed, mu0)
        self.theta = self.gaussian(*self.shape)

    def _propose(self):
        return self.theta + self.gaussian(*self.shape)

    def _update(self, thetas, scores) -> None:
        self.theta = thetas.copy()
