"""CMA-ES over handle displacements (the ``cma`` package)."""

from __future__ import annotations

import numpy as np

from grt.optimizers.base import Optimizer


class CMAESOptimizer(Optimizer):
    """CMA-ES (Hansen) on the flattened ``3H`` displacement vector, starting at ``mu0`` with step ``sigma``.

    Args:
        num_handles, population, sigma, seed, mu0: see :class:`~grt.optimizers.base.Optimizer`.
    """

    min_population = 2
    min_population_reason = "it adapts its search from the ranking of each iteration's candidates"

    def __init__(self, num_handles: int, population: int = 10, sigma: float = 0.001, seed: int = 0,
                 mu0: float = 0.0):
        super().__init__(num_handles, population, sigma, seed, mu0)
        import cma  # 0.8 s to import and only this optimizer needs it: loaded when one is built

        # Sample from our own generator, not numpy's global one (which other code may touch), so a
        # run replays exactly on resume.
        opts = {"popsize": self.population, "seed": int(seed) + 1, "verbose": -9, "verb_log": 0,
                "verb_disp": 0, "randn": lambda *shape: self.rng.standard_normal(shape)}
        self.es = cma.CMAEvolutionStrategy(np.full(3 * self.num_handles, self.mu0), self.sigma, opts)

    def _propose(self) -> np.ndarray:
        return np.asarray(self.es.ask())

    def _update(self, thetas: np.ndarray, scores: np.ndarray) -> None:
        self.es.tell(list(thetas.reshape(self.population, -1)), scores.tolist())
