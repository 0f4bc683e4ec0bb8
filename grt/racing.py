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


def _pmf(total: int, bad: int, n: int) -> list[float]:
    """Hypergeometric ``P(f failures among the first n of total | bad failures in all)``, ``f = 0..n``."""
    whole = math.comb(total, n)
    return [math.comb(bad, f) * math.comb(total - bad, n - f) / whole for f in range(n + 1)]


def _cdf(total: int, bad: int, n: int, f: int) -> float:
    return sum(_pmf(total, bad, n)[: f + 1])


def _stops(total: int, bad: int, at: tuple[int, ...], level: float) -> list[int]:
    """Per look, the most failures at which a candidate stops (``-1``: none) at per-look ``level``."""
    out = []
    for n in at:
        most = -1
        for f in range(n + 1):
            certain = f + (total - n) < bad  # even failing every remaining trial it cannot matter
            if certain or _cdf(total, bad, n, f) <= level + 1e-15:
                most = f
            else:
                break
        out.append(most)
    return out


def _risk(total: int, bad: int, at: tuple[int, ...], bounds: list[int]) -> float:
    """Exact probability that a candidate with ``bad`` failures among ``total`` is stopped at some look."""
    # state: failures seen so far -> probability of having got there without stopping
    alive, seen, stopped = {0: 1.0}, 0, 0.0
    for n, most in zip(at, bounds, strict=True):
        step = n - seen
        nxt: dict[int, float] = {}
        for f, p in alive.items():
            left, bad_left = total - seen, bad - f
            for g, q in enumerate(_pmf(left, bad_left, step)):
                if q:
                    nxt[f + g] = nxt.get(f + g, 0.0) + p * q
        stopped += sum(p for f, p in nxt.items() if f <= most)
        alive, seen = {f: p for f, p in nxt.items() if f > most}, n
    return stopped


@lru_cache(maxsize=4096)
def look_level(total: int, bad: int, at: tuple[int, ...], alpha: float) -> tuple[int, ...]:
    """Per look, the most failures seen at which a candidate stops, so that one with ``bad`` failures among
    ``total`` is stopped at any look with probability <= ``alpha``; the same per-look level at every look,
    the largest that keeps the exact risk (:func:`_risk`) within ``alpha`` (found among the attainable
    p-values). ``alpha = 0``: the deterministic bound only."""
    candidates = sorted({_cdf(total, bad, n, f) for n in at for f in range(n + 1)} | {0.0})
    candidates = [c for c in candidates if c <= alpha + 1e-15]
    best = _stops(total, bad, at, 0.0)
    lo, hi = 0, len(candidates) - 1
    while lo <= hi:  # the risk grows with the level: the largest level within alpha
        mid = (lo + hi) // 2
        bounds = _stops(total, bad, at, candidates[mid])
        if _risk(total, bad, at, bounds) <= alpha + 1e-12:
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
