"""Ask/tell interface of GRT's black-box searches over handle displacements.

A candidate ``theta`` is an ``(H, 3)`` array of handle displacements in **unit-cube units** (the
normalized mesh the deformation works in; the paper's σ = 0.001 is in these units). Scores are the
task metric of each candidate (success rate, drawer opening, ...): the red team **minimizes** them.

Optimizers are deterministic given their seed, which is what makes a run resumable: replaying
``ask``/``tell`` with the journaled scores reproduces the optimizer's state exactly.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import numpy as np


class Optimizer(ABC):
    """Base class: population bookkeeping and the best candidate seen so far.

    Args:
        num_handles: ``H``, handles per candidate.
        population: ``N``, candidates per iteration.
        sigma: standard deviation of the initial/perturbation Gaussian (unit-cube units).
        seed: seeds the optimizer's random generator.
        mu0: mean of the initial Gaussian (unit-cube units; the paper uses a zero mean).
    """

    #: the smallest population the method works with (``grt.config.validate`` checks it before a run).
    min_population: int = 1
    #: why a smaller population does not work (said when one is refused).
    min_population_reason: str = ""

    def __init__(self, num_handles: int, population: int = 10, sigma: float = 0.001, seed: int = 0,
                 mu0: float = 0.0):
        if num_handles < 1:
            raise ValueError(f"num_handles must be >= 1, got {num_handles}")
        if population < self.min_population:
            why = f" ({self.min_population_reason})" if self.min_population_reason else ""
            raise ValueError(f"{type(self).__name__} needs a population of at least {self.min_population}{why}, "
                             f"got {population}")
        if not 0 < sigma < math.inf:
            raise ValueError(f"sigma must be a finite number > 0 (unit-cube units), got {sigma}")
        if not math.isfinite(float(mu0)):
            raise ValueError(f"optimizer.mu0={mu0}: the mean of the first candidates must be a finite number "
                             "(unit-cube units; the paper's is 0)")
        self.num_handles, self.population = int(num_handles), int(population)
        self.sigma, self.mu0 = float(sigma), float(mu0)
        self.rng = np.random.default_rng(seed)
        self.iteration = 0
        self.best_theta: np.ndarray | None = None
        self.best_score = float("inf")
        self._asked: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(N, H, 3)``: the shape of a population."""
        return (self.population, self.num_handles, 3)

    def gaussian(self, *shape: int) -> np.ndarray:
        """Draws from ``N(mu0, sigma^2)`` of the given shape."""
        return self.mu0 + self.sigma * self.rng.standard_normal(shape)

    def ask(self) -> np.ndarray:
        """Propose the next population, ``(N, H, 3)`` unit-cube displacements."""
        if self._asked is not None:
            raise RuntimeError("ask() called twice without tell(): score the last population first")
        self._asked = np.asarray(self._propose(), np.float64).reshape(self.shape)
        return self._asked.copy()

    def tell(self, thetas: np.ndarray, scores: np.ndarray) -> None:
        """Report the scores of the population last asked.

        Args:
            thetas: ``(N, H, 3)`` the candidates as evaluated (after any budget projection).
            scores: ``(N,)`` their task metric; lower is better for the red team.
        """
        if self._asked is None:
            raise RuntimeError("tell() without ask()")
        thetas = np.asarray(thetas, np.float64).reshape(self.shape)
        scores = np.asarray(scores, np.float64).reshape(self.population)
        if not np.all(np.isfinite(scores)):
            raise ValueError(f"scores must be finite, got {scores}")
        i = int(np.argmin(scores))
        if scores[i] < self.best_score:
            self.best_score, self.best_theta = float(scores[i]), thetas[i].copy()
        self._update(thetas, scores)
        self._asked = None
        self.iteration += 1

    @abstractmethod
    def _propose(self) -> np.ndarray:
        """Return the population to evaluate next, ``(N, H, 3)``."""

    @abstractmethod
    def _update(self, thetas: np.ndarray, scores: np.ndarray) -> None:
        """Update the search state with evaluated ``thetas`` ``(N, H, 3)`` and ``scores`` ``(N,)``."""


def num_elites(population: int, elite_frac: float) -> int:
    """``ceil(rho * N)``, at least 1 (Algorithm 1)."""
    if not 0 < elite_frac <= 1:
        raise ValueError(f"elite_frac must be in (0, 1], got {elite_frac}")
    return max(1, int(np.ceil(elite_frac * population - 1e-9)))
