"""Run metrics over the scores of a red-team run: the paper's red-teaming metrics (appendix, lines 753-818)
computed from per-candidate scores (degradation curve, Final Drop, Iter@50%, AUC, ΔComplexity), and the 95%
intervals of one candidate's score (:func:`score_interval`).

What a score *is* (its name, unit, interval method and the task's nominal floor) is :mod:`grt.scores`; the
metrics here are relative to ``S0`` and do not need to know.

Conventions (stated because the paper leaves them open):

* ``S0`` is the nominal object's score (iteration 0); ``S_t`` is the **lowest** score seen up to and
  including iteration ``t`` (with ``S_0`` the nominal score), so the degradation curve
  ``C(t) = (S0 - S_t) / S0`` is non-decreasing and ``C(0) = 0``.
* Final Drop is ``max_theta (S0 - S_theta) / S0 = C(T)`` — a fraction (the paper's tables print %).
* Iter@50% is the first iteration ``t >= 1`` with ``S_t <= 0.5 S0``; when no candidate reaches it
  the budget ``T`` is reported and ``reached_50`` is false (the paper's Gaussian rows read 10.00 with
  T = 10, consistent with this).
* AUC is the trapezoid rule over ``t = 0..T`` with unit spacing, so its maximum is ``T``.
* Scores are any floats the task defines: a success rate in [0, 1] for binary tasks, or the mean of a
  continuous per-trial value (e.g. a drawer opening in meters). Every metric is relative to ``S0``, so
  it does not depend on the score's unit or range (multiplying every score by 100 changes nothing).
* With ``S0 <= 0`` (the policy already fails on the nominal object) relative drops are undefined:
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
        ``(T + 1,)`` relative degradation, NaN when ``s0 <= 0`` (a negative ``S0`` would flip its sign).
    """
    best = [float(s0)]
    for scores in iteration_scores:  # NaN = a candidate the simulator could not score: skipped
        best.append(min([best[-1], *(float(s) for s in scores if not math.isnan(float(s)))]))
    best = np.asarray(best)
    if not s0 > 0:
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


def iter_at_50_label(value, reached: bool | None) -> str:
    """Iter@50% as a person reads it: the iteration, or ``not reached in T`` (the value is then the budget
    ``T``, :func:`iter_at_50`; ``2 (not reached)`` read as "reached at 2")."""
    if value is None:
        return "-"
    return str(value) if reached or reached is None else f"not reached in {value}"


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
    """95% Wilson score interval of a binomial proportion (well-behaved at 0 and 1 and small n); it always holds
    the observed proportion (at 0 or 1 rounding would otherwise leave the bound a hair inside, e.g.
    0.9999999999999999 for 6 of 6)."""
    if n <= 0:
        return (float("nan"), float("nan"))
    p = successes / n
    denom = 1 + z * z / n
    center = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, min(p, center - half)), min(1.0, max(p, center + half)))


def mean_interval(values: Sequence[float], z: float = 1.96) -> tuple[float, float]:
    """Normal-approximation 95% interval of a mean (continuous metrics, e.g. drawer opening)."""
    v = np.asarray(values, np.float64)
    if v.size == 0:
        return (float("nan"), float("nan"))
    half = z * (v.std(ddof=1) / math.sqrt(v.size) if v.size > 1 else 0.0)
    return (float(v.mean() - half), float(v.mean() + half))


def bootstrap_interval(values: Sequence[float], n_boot: int = 2000, seed: int = 0) -> tuple[float, float]:
    """Percentile-bootstrap 95% interval of a mean (no normality assumed; skewed continuous scores).

    Args:
        values: ``(n,)`` per-trial scores.
        n_boot: resamples with replacement.
        seed: seeds the resampling, so the same values always give the same interval.

    Returns:
        The 2.5th and 97.5th percentiles of the ``n_boot`` resampled means (NaN without values).
    """
    v = np.asarray(values, np.float64)
    if v.size == 0:
        return (float("nan"), float("nan"))
    if n_boot < 1:
        raise ValueError(f"n_boot must be >= 1, got {n_boot}")
    means = v[np.random.default_rng(seed).integers(0, v.size, size=(n_boot, v.size))].mean(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    return (float(low), float(high))


CI_METHODS = ("auto", "wilson", "normal", "bootstrap")


def score_interval(values: Sequence[float], method: str = "auto") -> tuple[float, float]:
    """95% interval of the mean of per-trial scores by ``method`` (a task's ``ci`` setting).

    Args:
        values: ``(n,)`` per-trial scores (valid trials only).
        method: ``auto`` (Wilson when every score is 0 or 1, else normal), ``wilson``, ``normal`` or
            ``bootstrap`` (:func:`bootstrap_interval`, seed 0).

    Raises:
        ValueError: an unknown method, or ``wilson`` on scores that are not all 0 or 1.
    """
    if method not in CI_METHODS:
        raise ValueError(f"ci={method!r}: use one of {', '.join(CI_METHODS)}")
    v = np.asarray(values, np.float64)
    if v.size == 0:
        return (float("nan"), float("nan"))
    binary = bool(np.all((v == 0.0) | (v == 1.0)))
    if method == "auto":
        method = "wilson" if binary else "normal"
    if method == "wilson":
        if not binary:
            raise ValueError("ci=wilson is the interval of a success rate: it needs trial scores of 0 or 1 "
                             "(use normal or bootstrap for a continuous score)")
        return wilson_interval(float(v.sum()), int(v.size))
    if method == "normal":
        return mean_interval(v)
    return bootstrap_interval(v)


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
