"""Nevergrad's optimizers over handle displacements (``optimizer=nevergrad``, ``optimizer=nevergrad_tbpsa``)."""

from __future__ import annotations

import difflib
import warnings

import numpy as np

from grt.optimizers.base import Optimizer


def _registry() -> dict:
    import nevergrad as ng  # ~1.5 s to import and only these optimizers need it: loaded when one is built

    return ng.optimizers.registry


class NevergradOptimizer(Optimizer):
    """One of Nevergrad's ask/tell optimizers on the flattened ``3H`` displacement vector, started at ``mu0``
    with mutation scale ``sigma``, told the whole budget (``population x iterations`` candidates) and the
    population as its parallelism (``num_workers``), so a wizard such as ``NGOpt`` picks for this problem.

    Determinism: the parametrization's random state is seeded from ``seed``, and every draw of the optimizers
    used here comes from it, so a run replays exactly on resume (checked by the tests).

    Args:
        num_handles, population, sigma, seed, mu0: see :class:`~grt.optimizers.base.Optimizer`.
        iterations: ``T``; with ``population`` it is the budget Nevergrad plans for.
        method: a name of ``nevergrad.optimizers.registry`` (``NGOpt``: its recommended wizard; ``TBPSA``:
            population-size adaptation for noisy objectives).
    """

    def __init__(self, num_handles: int, population: int = 10, sigma: float = 0.001, seed: int = 0,
                 mu0: float = 0.0, iterations: int = 10, method: str = "NGOpt"):
        super().__init__(num_handles, population, sigma, seed, mu0)
        registry = _registry()
        if method not in registry:
            close = difflib.get_close_matches(method, list(registry), n=5, cutoff=0.5) or ["NGOpt", "TBPSA", "CMA"]
            raise ValueError(f"optimizer.method={method!r} is not a Nevergrad optimizer; close names: "
                             f"{', '.join(close)}")
        if iterations < 1:
            raise ValueError(f"iterations must be >= 1, got {iterations}")
        import nevergrad as ng

        param = ng.p.Array(init=np.full(3 * self.num_handles, self.mu0)).set_mutation(sigma=self.sigma)
        param.random_state = np.random.RandomState(int(seed))
        self.method = method
        with warnings.catch_warnings():  # e.g. "budget too small for this optimizer": the run says what it used
            warnings.simplefilter("ignore")
            self.ng = registry[method](parametrization=param, budget=self.population * int(iterations),
                                       num_workers=self.population)
        self._pending: list = []

    def _propose(self) -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self._pending = [self.ng.ask() for _ in range(self.population)]
        return np.stack([np.asarray(c.value, np.float64) for c in self._pending])

    def _update(self, thetas: np.ndarray, scores: np.ndarray) -> None:
        # told the candidates as asked: the loop evaluates their Smoothness-Score projection, so the objective
        # Nevergrad sees is the score of the projected shape (flat beyond the budget, as for every optimizer)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for cand, score in zip(self._pending, scores, strict=True):
                self.ng.tell(cand, float(score))
        self._pending = []
