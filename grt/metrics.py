"""The paper's red-teaming metrics (appendix, lines 753-818), computed from per-candidate scores.

Conventions (stated because the paper leaves them open):

* ``S0`` is the nominal object's score (iteration 0); ``S_t`` is the **lowest** score seen up to and
  including iteration ``t`` (with ``S_0`` the nominal score), so the degradation curve
  ``C(t) = (S0 - S_t) / S0`` is non-decreasing and ``C(0) = 0``.
* Final Drop is ``max_theta (S0 - S_theta) / S0 = C(T)`` — a fraction (the paper's tables print %).
* Iter@50% is the first iteration ``t >= 1`` with ``S_t <= 0.5 S0``; when no candidate reaches it
  the budget ``T`` is reported and ``reached_50`` is false (the paper's Gaussian rows read 10.00 with
  T = 10, consistent with this).
* AUC is the trapezoid rule over ``t = 0..T`` with unit spacing, so its maximum is ``T``.
* With ``S0 = 0`` (the policy already fails on the nominal object) relative drops are undefined:
  they are reported as NaN and the summary says why.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def degradation_curve(s0: float, iteration_scores: Sequence[Sequence[float]]) -> np.ndarray:
    """``C(t)`` for ``t = 0..T``.

    Args:
        s0: nominal score.
        iteration_scores: ``T`` lists, the scores of the candidates of iterations ``1..T``.

    Returns:
        ``(T + 1,)`` relative degradation, NaN when ``s0 == 0``.
    """
    best = [float(s0)]
    for scores in iteration_scores:  # NaN = a candidate the simulator could not score: skipped
        best.append(min([best[-1], *(float(s) for s in scores if not math.isnan(float(s)))]))
    best = np.asarray(best)
    if s0 == 0:
        return np.full(best.shape, np.nan)
    return (s0 - best) / s0


def final_drop(s0: float, iteration_scores: Sequence[Sequence[float]]) -> float:
    """``max_theta (S0 - S_theta) / S0`` over every candidate explored (0 if none is worse)."""
    return float(degradation_curve(s0, iteration_scores)[-1])


def auc(curve: np.ndarray) -> float:
    """Trapezoid rule ``sum_{t=1..T} (C(t) + C(t-1)) / 2``."""
    curve = np.asarray(curve, np.float64)
    return float(np.sum(0.5 * (curve[1:] + curve[:-1])))


def iter_at_50(curve: np.ndarray) -> tuple[int, bool]:
    """First ``t >= 1`` with ``C(t) >= 0.5`` (i.e. ``S_t <= S0 / 2``); ``(T, False)`` when never."""
    curve = np.asarray(curve, np.float64)
    hits = np.flatnonzero(curve[1:] >= 0.5 - 1e-12)
    if hits.size:
        return int(hits[0] + 1), True
    return int(len(curve) - 1), False


def delta_complexity(nominal_entropy: float, candidates: Sequence[tuple[float, float]], k: int = 10) -> float:
    """Median entropy increase of the ``k`` lowest-scoring shapes (paper: ten).

    Args:
        nominal_entropy: ``H(M)``, angular-deficit entropy of the nominal mesh.
        candidates: ``(score, entropy)`` of every explored shape.
        k: how many of the worst-performing shapes enter the median.

    Returns:
        ``median(H(T_theta(M)) - H(M))`` over the ``k`` lowest scores (NaN with no candidates).
    """
    candidates = [c for c in candidates if not math.isnan(c[0])]
    if not candidates:
        return float("nan")
    order = sorted(candidates, key=lambda c: c[0])[:k]
    return float(np.median([h - nominal_entropy for _, h in order]))


def wilson_interval(successes: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """95% Wilson score interval of a binomial proportion (well-behaved at 0 and 1 and small n)."""
    if n <= 0:
        return (float("nan"), float("nan"))
    p = successes / n
    denom = 1 + z * z / n
    center = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, center - half), min(1.0, center + half))


def mean_interval(values: Sequence[float], z: float = 1.96) -> tuple[float, float]:
    """Normal-approximation 95% interval of a mean (continuous metrics, e.g. drawer opening)."""
    v = np.asarray(values, np.float64)
    if v.size == 0:
        return (float("nan"), float("nan"))
    half = z * (v.std(ddof=1) / math.sqrt(v.size) if v.size > 1 else 0.0)
    return (float(v.mean() - half), float(v.mean() + half))


def summarize(s0: float, iteration_scores: Sequence[Sequence[float]]) -> dict:
    """Final Drop, AUC, Iter@50% and the curve, as stored in ``summary.json``."""
    curve = degradation_curve(s0, iteration_scores)
    it50, reached = iter_at_50(curve)
    return {
        "final_drop": float(curve[-1]),
        "auc": auc(curve),
        "iter_at_50": it50,
        "reached_50": reached,
        "curve": [None if math.isnan(c) else float(c) for c in curve],
    }
