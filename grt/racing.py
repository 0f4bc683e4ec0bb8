"""Racing a candidate's trials (``budget.racing``): stop simulating a candidate once it cannot matter.

A candidate's trials run in the run's fixed seed order, in rounds. After each round the candidate stops
when its full score (the mean over all ``N`` seeds, the number every metric compares) can no longer be
one that matters: a CrashShape (below ``S0`` by ``task.crash_margin``) that also beats the ``k``-th best
full-trial CrashShape of the earlier iterations (``budget.top_k``). A candidate that could matter runs
all ``N`` trials, so the run's CrashShapes, Final Drop and confirmation are made of full-trial candidates
on the common seeds.

The rule, for a binary score (a success rate; racing is refused for continuous scores):

* ``F_min`` is the fewest failures out of ``N`` that make the candidate matter (:func:`failures_needed`).
* The seeds were drawn at random, so for a candidate with ``K`` failures among its ``N`` seeds, its first
  ``n`` seeds are a simple random sample of them: the failures among them are hypergeometric
  ``(N, K, n)``. A candidate that matters has ``K >= F_min``; the hardest of those to tell from one that
  does not is ``K = F_min`` (more failures make an early stop less likely).
* The candidate stops at a look ``n`` when the failures seen, ``f``, are so few that a candidate with
  ``F_min`` failures would show ``f`` or fewer with probability at most ``alpha_look``
  (:func:`look_level`): ``alpha_look`` is the largest level at which the probability that a candidate
  with exactly ``F_min`` failures is stopped at *any* look, computed exactly over the looks (no normal
  approximation, no union bound), stays at most ``alpha`` (``budget.race_alpha``). So a candidate that
  matters is stopped with probability at most ``alpha``.
* Always, whatever ``alpha``: when even ``N - n`` failures in the remaining trials could not reach
  ``F_min`` (the deterministic bound, probability 0 above). ``alpha = 0`` keeps only this bound: no
  candidate that matters is ever stopped.

Why, and what the statistical bound cost when replayed on full-trial journals: docs/decisions.md ("Racing").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from grt.scores import is_crash

#: why a candidate stopped (the journal's ``race.stopped``)
NOT_CRASH = "cannot be a CrashShape"
NOT_TOP_K = "cannot beat the top-k"


def looks(trials: int, rounds: int) -> tuple[int, ...]:
    """The trial counts after which a candidate is judged: ``rounds`` rounds of about equal size (at least
    one trial each), the last one ending at ``trials`` (not a look: nothing is left to save)."""
    if trials < 1 or rounds < 1:
        raise ValueError(f"trials and rounds must be >= 1, got {trials}, {rounds}")
    rounds = min(rounds, trials)
    return tuple(sorted({round(trials * j / rounds) for j in range(1, rounds)} - {0, trials}))


def failures_needed(trials: int, s0: float, margin: float, kth: float | None) -> int | None:
    """The fewest failures out of ``trials`` for which the candidate's success rate is a CrashShape
    (:func:`grt.scores.is_crash`) and, with ``kth`` (the ``k``-th best full-trial CrashShape so far), beats it
    (strictly lower: an equal score ranks after the earlier one). ``None``: no count does."""
    for failures in range(trials + 1):
        score = (trials - failures) / trials
        if is_crash(score, s0, margin) and (kth is None or score < kth - 1e-12):
            return failures
    return None


def _tail(total: int, bad: int, n: int, alpha: float) -> np.ndarray:
    """Hypergeometric ``P(f or fewer failures among the first n of total | bad failures in all)`` for
    ``f = 0, 1, ...`` up to and including the first value above ``alpha`` (or ``f = n``): the lower tail, the only
    part a stop at level ``<= alpha`` reads. Each term is exact big-integer arithmetic rounded once to a float
    (``C(bad, f) C(total - bad, n - f) / C(total, n)``), the tail their running sum."""
    low, high = max(0, n - (total - bad)), min(n, bad)  # the support
    whole, terms = math.comb(total, n), [0.0] * low
    term = math.comb(bad, low) * math.comb(total - bad, n - low)
    cdf = 0.0
    for f in range(low, high + 1):
        cdf += term / whole  # int / int: rounded once
        terms.append(cdf)
        if cdf > alpha + 1e-15:
            break
        term = term * (bad - f) * (n - f) // ((f + 1) * (total - bad - n + f + 1)) if f < high else 0
    return np.maximum.accumulate(np.asarray(terms or [0.0]))


def _stops(total: int, bad: int, at: tuple[int, ...], level: float, tails: list[np.ndarray] | None = None,
           ) -> list[int]:
    """Per look, the most failures at which a candidate stops (``-1``: none) at per-look ``level``: those whose
    tail probability is at most ``level``, and those that even failing every remaining trial cannot reach
    ``bad`` (both a prefix of ``f = 0, 1, ...``, so the larger end is the bound)."""
    tails = tails or [_tail(total, bad, n, level) for n in at]
    out = []
    for n, tail in zip(at, tails, strict=True):
        certain = bad - (total - n) - 1  # f + (total - n) < bad
        by_level = int(np.searchsorted(tail, level + 1e-15, side="right")) - 1
        out.append(min(n, max(certain, by_level)))
    return out


def _kernel(left: int, bad_left: np.ndarray, step: int) -> np.ndarray:
    """``P(g failures among the next step of left trials | bad_left failures in them)``, ``g = 0..step``, one
    row per ``bad_left``. Each row is the pmf's ratio recurrence summed in log space from its mode, normalised
    over its whole support (relative error ~1e-13, far below the rule's 1e-12 tolerance; no big integers)."""
    k = bad_left[:, None].astype(np.float64)
    low = np.maximum(0, step - (left - bad_left))[:, None]
    high = np.minimum(step, bad_left)[:, None]
    mode = np.clip((step + 1) * (bad_left + 1) // (left + 2), low[:, 0], high[:, 0])
    g = np.arange(step, dtype=np.float64)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):  # outside the support: masked below
        ratio = np.log((k - g) * (step - g)) - np.log((g + 1) * (left - k - step + g + 1))
    log_p = np.concatenate([np.zeros((len(k), 1)), np.cumsum(np.where((g >= low) & (g < high), ratio, 0.0),
                                                             axis=1)], axis=1)
    g_all = np.arange(step + 1)[None, :]
    support = (g_all >= low) & (g_all <= high)
    p = np.where(support, np.exp(np.where(support, log_p - log_p[np.arange(len(k)), mode][:, None], -np.inf)), 0.0)
    return p / p.sum(axis=1, keepdims=True)


class _Steps:
    """The kernels of the steps between looks (:func:`_kernel`), made once per state and reused by every risk
    :func:`look_level` computes for one ``(total, bad, at)``: per look, the rows of a range of states."""

    def __init__(self, total: int, bad: int, at: tuple[int, ...]):
        self.total, self.bad, self.at = total, bad, at
        self.rows: list[tuple[int, np.ndarray]] = [(0, np.zeros((0, n - (at[j - 1] if j else 0) + 1)))
                                                    for j, n in enumerate(at)]

    def __call__(self, j: int, first: int, last: int) -> np.ndarray:
        """The kernel rows of the step into look ``j`` from the states ``first..last`` (failures seen at the
        look before)."""
        lo, known = self.rows[j]
        if not len(known):
            lo = first
        seen = self.at[j - 1] if j else 0
        make = lambda a, b: _kernel(self.total - seen, self.bad - np.arange(a, b), self.at[j] - seen)  # noqa: E731
        if first < lo:
            known, lo = np.concatenate([make(first, lo), known]), first
        if last >= lo + len(known):
            known = np.concatenate([known, make(lo + len(known), last + 1)])
        self.rows[j] = (lo, known)
        return known[first - lo: last - lo + 1]


def _shifted_sum(rows: np.ndarray, first: int, size: int) -> np.ndarray:
    """``out[first + i + g] += rows[i, g]`` (row ``i`` shifted right by ``first + i``), cut at ``size``: each
    row laid out one place further than the one above in a flat buffer (no scatter)."""
    count, width = rows.shape
    skew = np.zeros((count, width + count))
    skew[:, :width] = rows
    summed = skew.ravel()[: count * (width + count - 1)].reshape(count, width + count - 1).sum(axis=0)
    out = np.zeros(size)
    end = min(size, first + len(summed))
    out[first:end] = summed[: end - first]
    return out


def _risk(total: int, bad: int, at: tuple[int, ...], bounds: list[int], steps: _Steps | None = None) -> float:
    """Exact probability that a candidate with ``bad`` failures among ``total`` is stopped at some look.

    Failures only accumulate, so a state above every later look's bound is never stopped: only the states at
    or below the largest bound still to come are carried from look to look (the probability of each is that
    of reaching it without having been stopped).
    """
    steps = steps or _Steps(total, bad, at)
    later = np.maximum.accumulate(np.asarray(bounds, dtype=np.int64)[::-1])[::-1]  # max bound from each look on
    alive, first, stopped = np.ones(1), 0, 0.0
    for j, (most, top) in enumerate(zip(bounds, later.tolist(), strict=True)):
        live = np.flatnonzero(alive[: top - first + 1] > 0)  # a state of mass 0 carries nothing
        if not len(live):
            break
        lo, hi = first + int(live[0]), first + int(live[-1])
        mass = alive[lo - first: hi - first + 1]
        new = _shifted_sum(mass[:, None] * steps(j, lo, hi)[:, : top - lo + 1], lo, top + 1)
        stopped += float(new[: most + 1].sum())
        first, alive = most + 1, new[most + 1:]
    return stopped


@lru_cache(maxsize=4096)
def look_level(total: int, bad: int, at: tuple[int, ...], alpha: float) -> tuple[int, ...]:
    """Per look, the most failures seen at which a candidate stops, so that one with ``bad`` failures among
    ``total`` is stopped at any look with probability <= ``alpha``; the same per-look level at every look,
    the largest that keeps the exact risk (:func:`_risk`) within ``alpha`` (found among the attainable
    p-values). ``alpha = 0``: the deterministic bound only.

    Its cost grows with the tails and the bounds, not with ``total`` squared: about a millisecond to tens of
    milliseconds from 64 to 4096 trials (``python -m grt.bench racing rule``)."""
    tails = [_tail(total, bad, n, alpha) for n in at]
    candidates = sorted({float(c) for tail in tails for c in tail if c <= alpha + 1e-15} | {0.0})
    best, steps = _stops(total, bad, at, 0.0, tails), _Steps(total, bad, at)
    lo, hi = 0, len(candidates) - 1
    while lo <= hi:  # the risk grows with the level: the largest level within alpha
        mid = (lo + hi) // 2
        bounds = _stops(total, bad, at, candidates[mid], tails)
        if _risk(total, bad, at, bounds, steps) <= alpha + 1e-12:
            best, lo = bounds, mid + 1
        else:
            hi = mid - 1
    return tuple(best)


@dataclass(frozen=True)
class Race:
    """The racing rule of one iteration's candidates (same for each: it depends on earlier iterations only,
    so decisions do not depend on which worker finished first).

    Args:
        trials: ``N``, the run's trials per candidate.
        rounds: ``budget.race_rounds``.
        alpha: ``budget.race_alpha``.
        s0: the nominal score; margin: ``task.crash_margin``.
        kth: the ``k``-th best full-trial CrashShape score of the earlier iterations (``None``: fewer than k).
    """

    trials: int
    rounds: int
    alpha: float
    s0: float
    margin: float
    kth: float | None = None

    @property
    def at(self) -> tuple[int, ...]:
        return looks(self.trials, self.rounds)

    def stop(self, scores: list[float], errors: int = 0) -> dict | None:
        """Whether a candidate whose first ``len(scores)`` trials (valid ones) scored ``scores`` stops now.

        Returns ``None`` (go on) or ``{"stopped": reason, "needed": F_min, "failures": f}``. A candidate
        with a ``sim_error`` among its trials goes on (its full score's count of valid trials is unknown).
        """
        n = len(scores) + errors
        if errors or n not in self.at or not self.s0 > 0:
            return None
        failures = sum(1 for s in scores if s < 0.5)
        needed = failures_needed(self.trials, self.s0, self.margin, None)
        reason = NOT_CRASH
        if needed is not None and self.kth is not None:
            top = failures_needed(self.trials, self.s0, self.margin, self.kth)
            reason, needed = (NOT_TOP_K, top) if top is None or top > needed else (reason, needed)
        if needed is None:  # no score it could reach matters
            return {"stopped": reason, "needed": None, "failures": failures}
        bounds = look_level(self.trials, needed, self.at, float(self.alpha))
        if failures <= bounds[self.at.index(n)]:
            return {"stopped": reason, "needed": needed, "failures": failures}
        return None


def kth_best(records: list[dict], k: int, s0: float, margin: float, before: int) -> float | None:
    """The ``k``-th lowest full-trial CrashShape score among journal ``records`` of iterations ``1..before-1``
    (``None`` with fewer than ``k``): what a later candidate must beat to enter the top ``k``."""
    scores = sorted(r["score"] for r in records if 1 <= r["iteration"] < before and r["score"] == r["score"]
                    and is_crash(r["score"], s0, margin))
    return scores[k - 1] if len(scores) >= k else None


@dataclass(frozen=True)
class Racing:
    """A run's racing settings (``budget.racing``, ``race_rounds``, ``race_alpha``; ``budget.top_k``;
    ``task.crash_margin``); :meth:`for_iteration` makes each iteration's :class:`Race`."""

    rounds: int
    alpha: float
    top_k: int
    margin: float

    def for_iteration(self, trials: int, s0: float, records: list[dict], t: int) -> Race:
        """The rule for iteration ``t``'s candidates, from the journal's full-trial records before ``t``."""
        return Race(trials, self.rounds, self.alpha, s0, self.margin, kth_best(records, self.top_k, s0, self.margin, t))

    def fields(self) -> dict:
        """What ``summary.json`` records of the settings."""
        return {"rounds": self.rounds, "alpha": self.alpha, "top_k": self.top_k, "crash_margin": self.margin}


def stopped(record: dict) -> bool:
    """Whether a journal record is a candidate racing stopped before its last trial."""
    return bool((record.get("race") or {}).get("stopped"))


def search_score(record: dict) -> float:
    """The score the search is told for a journal record: a stopped candidate's mean over the trials it ran
    (its journaled ``score`` is NaN: it has no full-trial score, so no metric counts it)."""
    return float(record["race"]["score"]) if stopped(record) else float(record["score"])


def trials_used(records: list[dict]) -> int:
    """Simulator trials behind the journal ``records`` (a stopped candidate counts the trials it ran)."""
    return sum(len(r.get("trials") or []) for r in records)


def search_figures(records: list[dict], confirmation: dict | None = None) -> dict:
    """What a search cost in simulator trials, from its journal ``records`` (and its ``confirm`` block):

    * ``trials_used``: every trial run (nominal included; a raced-out candidate counts the trials it ran);
    * ``trials_curve``: trials used by the end of iteration ``t = 0..T`` (the x-axis of a degradation curve
      against trials);
    * ``trials_to_first_crash``: trials used when the first full-trial CrashShape of the top-k was journaled
      (candidates in journal order; ``None``: none), and ``trials_to_first_confirmed``: the same for the first
      one whose drop the fresh-episode confirmation found significant (``None``: none confirmed, or no
      confirmation).
    """
    curve: list[int] = []
    used, at = 0, {}
    for rec in records:
        while len(curve) < rec["iteration"]:
            curve.append(used)
        used += len(rec.get("trials") or [])
        at[(rec["iteration"], rec["candidate"])] = used
    curve.append(used)
    shapes = (confirmation or {}).get("shapes") or []
    crashes = [at.get((s["iteration"], s["candidate"])) for s in shapes]
    confirmed = [at.get((s["iteration"], s["candidate"])) for s in shapes if s.get("confirmed")]
    return {"trials_used": used, "trials_curve": curve,
            "trials_to_first_confirmed": min(confirmed) if confirmed else None,
            "trials_to_first_crash": min(crashes) if crashes else None}
