"""The noise floor of Final Drop: what a search of a run's protocol would report if no deformation mattered.

Final Drop is the relative drop of the *lowest* of ``N`` candidate scores, each the mean of ``T`` trials.
Even when every candidate truly scores as the nominal object does, the lowest of ``N`` noisy means lies
below ``S0``: the winner's curse. :func:`noise_floor` gives the distribution of that null Final Drop for a
run's protocol (candidates the search simulated, trials per candidate, the nominal's own trials), so a
table can print the measured Final Drop beside it.

The null model draws every trial of every candidate afresh from the nominal object's outcome distribution
(a deformation that changes nothing except which episodes the policy happens to win). It is the noisiest
null: a deterministic policy under common random numbers repeats the nominal's outcomes seed for seed, and
its floor is lower. So a Final Drop below the floor says nothing about the geometry, and one above it is
worth confirming on fresh episodes (:mod:`grt.confirm`), which is what means something.

- Binary scores (success rates): exact. The nominal's success probability ``p`` is not known, only its
  ``k`` successes in ``n`` trials (8/8 does not prove ``p = 1``), so ``p`` follows the Jeffreys posterior
  ``Beta(k + 1/2, n - k + 1/2)``; given ``p`` the lowest count of ``N`` binomial(``T``, ``p``) draws has
  ``P(min >= j) = P(X >= j)^N``, and the floor integrates that over the posterior (Gauss-Legendre on the
  posterior's quantiles).
- Continuous scores (a drawer's opening): a seeded bootstrap of the nominal's per-trial values, each null
  candidate the mean of ``T`` values drawn with replacement (the normal approximation of that mean when
  ``T`` is large).

The observed ``S0`` is held fixed (the table's Final Drop is relative to it). Racing does not move the floor:
it stops only candidates that can no longer be among the lowest (at most ``race_alpha`` wrongly), so the
lowest of the candidates the search simulated is what the null gives too; ``top_k`` does not enter Final
Drop at all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

#: the upper quantile printed beside the mean: a Final Drop above it happens by luck in 5% of null searches
QUANTILE = 0.95
#: bootstrap replicates of a continuous score's null search
REPLICATES = 4000
#: Gauss-Legendre nodes over the posterior of the nominal's success probability
NODES = 64
#: trials per candidate above which a bootstrap mean is drawn from its normal approximation
NORMAL_ABOVE = 256
METHOD_BINARY = ("exact: lowest of N binomial(T, p) candidate scores, p from the nominal's Jeffreys posterior "
                 "Beta(k + 1/2, n - k + 1/2), S0 as observed")
METHOD_CONTINUOUS = "bootstrap of the nominal's per-trial scores ({} replicates, seed {}), S0 as observed"


def noise_floor(nominal_scores: Sequence[float], candidates: int, trials: int, observed: float | None = None,
                seed: int = 0) -> dict:
    """The null distribution of Final Drop for a search of ``candidates`` x ``trials`` against this nominal.

    Args:
        nominal_scores: ``(n,)`` the nominal object's per-trial scores (valid trials; NaN are dropped).
            All 0 or 1: a success rate (exact); otherwise a continuous score (bootstrap).
        candidates: ``N``, the candidates the search simulated (implausible ones, never simulated, are not
            counted; candidates stopped by racing are).
        trials: ``T``, the trials behind each candidate's score.
        observed: the run's Final Drop (a fraction), for its ``p_value`` under the null.
        seed: seeds the bootstrap (continuous scores), so a summary is the same every time.

    Returns:
        ``{"mean", "q95", "p_value", "candidates", "trials", "nominal_trials", "s0", "method"}``: the null
        Final Drop's mean and 95th percentile (fractions of S0), ``P(null Final Drop >= observed)``
        (``None`` without ``observed``). Every figure is NaN when ``S0 <= 0`` or nothing was simulated.
    """
    x = np.asarray(nominal_scores, np.float64)
    x = x[np.isfinite(x)]
    s0 = float(x.mean()) if x.size else float("nan")
    out = {"candidates": int(candidates), "trials": int(trials), "nominal_trials": int(x.size), "s0": s0}
    binary = bool(x.size) and bool(np.all((x == 0.0) | (x == 1.0)))
    out["method"] = METHOD_BINARY if binary else METHOD_CONTINUOUS.format(REPLICATES, seed)
    if not (s0 > 0) or candidates < 1 or trials < 1:
        return {**out, "mean": float("nan"), "q95": float("nan"), "p_value": None if observed is None else float("nan")}
    values, probs = (_binary_null(int(x.sum()), int(x.size), candidates, trials) if binary
                     else _bootstrap_null(x, candidates, trials, seed))
    mean = float(np.dot(values, probs))
    order = np.argsort(values, kind="stable")
    cdf = np.cumsum(probs[order])
    q95 = float(values[order][min(int(np.searchsorted(cdf, QUANTILE - 1e-12)), len(cdf) - 1)])
    p_value = None if observed is None else float(np.sum(probs[values >= float(observed) - 1e-9]))
    return {**out, "mean": mean, "q95": q95, "p_value": p_value}


def fixed_p_floor(p: float, candidates: int, trials: int) -> tuple[float, float]:
    """Mean and 95th percentile of the null Final Drop when the success probability ``p`` is known and
    ``S0 = p`` (the protocol tables of docs/benchmarks.md): the exact binomial case without the posterior."""
    values, probs = _min_count_drop(np.array([p]), np.array([1.0]), p, candidates, trials)
    order = np.argsort(values, kind="stable")
    cdf = np.cumsum(probs[order])
    return float(np.dot(values, probs)), float(values[order][int(np.searchsorted(cdf, QUANTILE - 1e-12))])


def _binary_null(k: int, n: int, candidates: int, trials: int) -> tuple[np.ndarray, np.ndarray]:
    """Null Final Drop values ``(T + 1,)`` (one per lowest success count) and their probabilities."""
    from scipy import stats

    nodes, weights = np.polynomial.legendre.leggauss(NODES)
    u = 0.5 * (nodes + 1.0)  # quantiles of the posterior in (0, 1): equal mass per unit of u
    p = stats.beta.ppf(u, k + 0.5, n - k + 0.5)
    return _min_count_drop(p, 0.5 * weights, k / n, candidates, trials)


def _min_count_drop(p: np.ndarray, weights: np.ndarray, s0: float, candidates: int,
                    trials: int) -> tuple[np.ndarray, np.ndarray]:
    """Mix over ``p`` (with ``weights``) the distribution of the lowest of ``candidates`` binomial counts."""
    from scipy import stats

    j = np.arange(trials + 1)
    at_least = stats.binom.sf(j[None, :] - 1, trials, p[:, None])  # P(X >= j) per p: (P, T + 1)
    min_at_least = at_least ** candidates
    pmf = min_at_least - np.concatenate([min_at_least[:, 1:], np.zeros((len(p), 1))], axis=1)
    probs = np.clip(weights @ pmf, 0.0, None)
    probs = probs / probs.sum()
    values = np.maximum(0.0, (s0 - j / trials) / s0)
    return values, probs


def _bootstrap_null(x: np.ndarray, candidates: int, trials: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``REPLICATES`` null Final Drops of a continuous score, each with probability ``1 / REPLICATES``."""
    rng = np.random.default_rng([seed, 0x6E756C6C])  # "null": apart from every other stream of the run
    s0 = float(x.mean())
    lowest = np.empty(REPLICATES)
    chunk = max(1, int(2e6 // max(1, candidates * min(trials, NORMAL_ABOVE))))
    for start in range(0, REPLICATES, chunk):
        reps = min(chunk, REPLICATES - start)
        if trials > NORMAL_ABOVE:  # the mean of many draws: its normal approximation
            sd = float(x.std()) / math.sqrt(trials)
            means = s0 + sd * rng.standard_normal((reps, candidates))
        else:
            means = x[rng.integers(0, x.size, size=(reps, candidates, trials))].mean(axis=2)
        lowest[start:start + reps] = means.min(axis=1)
    values = np.maximum(0.0, (s0 - lowest) / s0)
    return values, np.full(REPLICATES, 1.0 / REPLICATES)


def simulated_candidates(records: Sequence[dict]) -> int:
    """``N`` for :func:`noise_floor`: the explored candidates the search simulated (journal records of
    iterations >= 1 scored, or stopped by racing; implausible ones were never simulated, and one whose every trial
    was a simulator error has no score)."""
    return sum(1 for r in records if r["iteration"] >= 1 and r.get("trials")
               and (r["score"] == r["score"] or (r.get("race") or {}).get("stopped")))
