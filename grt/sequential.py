"""A sequential paired test of one shape against the nominal object: stop its trials once the answer is clear.

Shrinking a CrashShape (:mod:`grt.shrink`) and the adversarial side of a robustness profile
(:mod:`grt.profile`) ask of many shapes the question the confirmation asks of each CrashShape: does this
shape score lower than the nominal object on the same fresh episodes, at the run's significance level? Most
shapes answer it long before the last episode: a shape that fails every episode the nominal object passes is
clear after a handful of them, one that fails none cannot become significant in the episodes left.
:class:`PairedTest` is a race-like rule (``at``, ``stop(scores, errors)``, the interface of
:class:`grt.racing.Race`) that the evaluators' ``evaluate_each(..., race=)`` runs in rounds.

The rule for a success rate (scores 0 or 1): per episode the difference ``shape - nominal`` is -1, 0 or +1.
Under the null hypothesis (the shape does not change the policy's success) each non-zero difference is -1
or +1 with probability 1/2, independently of which episodes have one: the one-sided paired sign-flip test
of :mod:`grt.confirm` is then the exact sign test on the discordant episodes. Looked at after each round,
the count of -1s is a fair-coin random walk observed at the discordant counts the data gave, and an
**error-spending** boundary keeps the probability of ever rejecting at most ``alpha``: at the look after
``n`` of ``N`` episodes, the boundary is the smallest count of -1s whose probability of being reached for
the first time at this look or earlier, computed exactly over the looks so far (a small dynamic programme
over the walk), stays within ``alpha * n / N``. Linear spending rejects a shape with a large drop at the
first looks and leaves the last look most of ``alpha``. A shape also stops unconfirmed once even failing
every later episode the nominal object passes could not reach a boundary, or when, past half its episodes,
it has failed no more of the nominal object's successes than it passed of its failures (no drop seen).
Stopping for futility never confirms anything, so it spends no error (a non-binding futility rule): it
can only cost power, a level left unconfirmed that the last episodes might have confirmed.

A continuous score (the drawer's opening) has no exact sequential form here: its shape runs every episode
and is judged by the fixed-sample sign-flip test at ``alpha``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import trimesh

from grt.confirm import paired_drop_p
from grt.geometry.mesh import mesh_hash
from grt.journal import InOrder, Journal, JournalError
from grt.metrics import score_interval
from grt.racing import looks

#: why a shape's trials stopped (``race.stopped`` in a journal record)
CONFIRMED = "drop confirmed"
CANNOT_CONFIRM = "cannot be confirmed"
TEST = ("one-sided paired sign test per episode (sign-flip for a continuous score), looked at after each "
        "round with linear error spending")


@lru_cache(maxsize=8192)
def _binom(m: int) -> tuple[float, ...]:
    """``P(k of m fair coins come up)``, ``k = 0..m``."""
    return tuple(math.comb(m, k) / 2.0**m for k in range(m + 1))


@lru_cache(maxsize=8192)
def boundaries(discordant: tuple[int, ...], spend: tuple[float, ...]) -> tuple[int, ...]:
    """Per look, the fewest -1 differences that reject (``m + 1``: none can).

    Args:
        discordant: the count of non-zero differences at each look so far (non-decreasing).
        spend: the error spent by each look (non-decreasing, the last at most ``alpha``).

    Returns:
        ``c_l`` per look: under the null hypothesis, the probability that the count of -1s reaches
        ``c_l`` at look ``l`` for the first time, summed over the looks up to ``l``, is at most
        ``spend[l]``, and ``c_l`` is the smallest count for which it is.
    """
    alive = {0: 1.0}  # -1 count -> probability of getting there without a rejection
    seen, spent, out = 0, 0.0, []
    for m, budget in zip(discordant, spend, strict=True):
        nxt: dict[int, float] = {}
        for k, p in alive.items():
            for j, q in enumerate(_binom(m - seen)):
                nxt[k + j] = nxt.get(k + j, 0.0) + p * q
        bound, tail = m + 1, 0.0
        for k in range(m, -1, -1):  # lower the boundary while the first-passage mass stays within budget
            mass = nxt.get(k, 0.0)
            if spent + tail + mass > budget + 1e-12:
                break
            tail, bound = tail + mass, k
        spent += tail
        alive = {k: p for k, p in nxt.items() if k < bound}
        seen = m
        out.append(bound)
    return tuple(out)


@dataclass(frozen=True)
class PairedTest:
    """The sequential paired test of shapes against the nominal object's scores on the same seeds.

    Args:
        nominal: the nominal object's score on each of the ``N`` seeds, in seed order (NaN: a ``sim_error``).
        alpha: the test's level (already divided among the shapes of a family, :mod:`grt.shrink`).
        rounds: rounds of about equal size the ``N`` trials run in (1: one fixed-sample test).
        binary: the score is a success rate (0 or 1 per trial); else no early decision.
    """

    nominal: tuple[float, ...]
    alpha: float
    rounds: int
    binary: bool = True

    @property
    def trials(self) -> int:
        return len(self.nominal)

    @property
    def at(self) -> tuple[int, ...]:
        """Trial counts after which a shape is judged (not the last: the final verdict is :meth:`verdict`)."""
        return looks(self.trials, self.rounds) if self.binary else ()

    def stop(self, scores: list[float], errors: int = 0) -> dict | None:
        """Whether a shape whose first ``len(scores)`` trials scored ``scores`` stops now (the race interface).

        Returns ``None`` (go on) or ``{"stopped": CONFIRMED | CANNOT_CONFIRM, "negatives": k, "discordant": m,
        "bound": c}``. A shape with a ``sim_error`` among its trials goes on (the pairing of its scores to the
        seeds is not known from the scores alone); it is judged on all its trials.
        """
        n = len(scores) + errors
        if errors or not self.binary or n not in self.at:
            return None
        state = self._state(scores)
        if state["negatives"] >= state["bound"]:
            return {"stopped": CONFIRMED, **state}
        if not self._reachable(scores) or (2 * n >= self.trials and 2 * state["negatives"] <= state["discordant"]):
            return {"stopped": CANNOT_CONFIRM, **state}
        return None

    def verdict(self, scores: list[float]) -> dict:
        """The decision on a shape's trials, ``scores`` in seed order (NaN: ``sim_error``; all ``N`` of them
        or, for a shape :meth:`stop` stopped, the first ones): ``confirmed``, ``p_value`` (the fixed-sample
        sign-flip p-value of the trials run, for the record) and, for a success rate, the counts
        (``negatives``, ``discordant``, ``bound``). An episode where either scored
        NaN counts as no difference."""
        n = len(scores)
        shape, nominal = np.asarray(scores, np.float64), np.asarray(self.nominal[:n], np.float64)
        p = paired_drop_p(shape, nominal)
        lower = bool(np.nanmean(shape) < np.nanmean(nominal)) if np.isfinite(shape).any() else False
        if not self.binary:
            return {"confirmed": bool(p <= self.alpha and lower), "p_value": p}
        state = self._state(list(shape))
        looked = n in self.at or n == self.trials
        return {"confirmed": bool(looked and state["negatives"] >= state["bound"]), "p_value": p, **state}

    # ------------------------------------------------------------------------------------------ helpers
    def _looks_until(self, n: int) -> tuple[int, ...]:
        return tuple(a for a in (*self.at, self.trials) if a <= n)

    def _spend(self, at: tuple[int, ...]) -> tuple[float, ...]:
        return tuple(self.alpha * a / self.trials for a in at)

    def _counts(self, scores: list[float], at: tuple[int, ...]) -> tuple[tuple[int, ...], int]:
        d = np.asarray(scores, np.float64) - np.asarray(self.nominal[:len(scores)], np.float64)
        d = np.where(np.isfinite(d), d, 0.0)
        discordant = tuple(int(np.count_nonzero(d[:a])) for a in at)
        return discordant, int(np.count_nonzero(d < 0))

    def _state(self, scores: list[float]) -> dict:
        at = self._looks_until(len(scores))
        discordant, negatives = self._counts(scores, at)
        bound = boundaries(discordant, self._spend(at))[-1] if at else len(scores) + 1
        return {"negatives": negatives, "discordant": discordant[-1] if at else 0, "bound": int(bound)}

    def _reachable(self, scores: list[float]) -> bool:
        """Whether some later look could still reject: the most favourable rest (every later episode the
        nominal object passes failed, every other one failed too: no +1) checked at each later look."""
        n = len(scores)
        best = list(scores) + [0.0] * (self.trials - n)  # a -1 wherever the nominal object passes, else a 0
        for a in (*self.at, self.trials):
            if a <= n:
                continue
            state = self._state(best[:a])
            if state["negatives"] >= state["bound"]:
                return True
        return False


@dataclass
class Chain:
    """Levels of one shape tested in a fixed order until the first not confirmed (:func:`descend`).

    Args:
        key: the chain's ``iteration`` in the journal (a CrashShape's rank, a direction's number).
        levels: per level, its journal fields (``alpha``, ``size_mm`` ...) and its mesh (meters).
    """

    key: int
    levels: list[tuple[dict, trimesh.Trimesh]]


def trial_scores(result) -> list[float]:
    """A result's per-trial scores in seed order (NaN for a ``sim_error``)."""
    return [float(o.score) if o.mode != "sim_error" else float("nan") for o in result.trials]


def evaluation_record(base: dict, result, ci: str) -> dict:
    """A journal record of one shape scored on fresh seeds: ``base`` and the score, interval and trials."""
    scores = trial_scores(result)
    return {**base, "score": float(result.score), "ci95": list(score_interval([s for s in scores if s == s], ci)),
            "trials": [{"seed": o.seed, "score": s, "mode": o.mode} for o, s in zip(result.trials, scores, strict=True)]}


def check_replay(journal: Journal, rec: dict, mesh: trimesh.Trimesh, seeds: list[int]) -> None:
    """Refuse a journal record made for another shape or other seeds than a replay expects."""
    ran = [t["seed"] for t in rec["trials"]]
    if rec["mesh_hash"] != mesh_hash(mesh.vertices, mesh.faces) or ran != seeds[:len(ran)]:
        raise JournalError(f"{journal.path}: the record of ({rec['iteration']}, {rec['candidate']}) was made for "
                           "another shape or other episodes; delete the file to measure again")


def score_shapes(journal: Journal, shapes: list[tuple[dict, trimesh.Trimesh]], evaluator, seeds: list[int],
                 ci: str = "auto", on_done=None) -> list[dict]:
    """Score each shape on every seed (no early stop), journaled in order; records already in ``journal``
    (keyed by ``base["iteration"], base["candidate"]``) are replayed. Returns the records, in order."""
    got: list[dict | None] = [None] * len(shapes)
    todo = []
    for k, (base, mesh) in enumerate(shapes):
        rec = journal.get(base["iteration"], base["candidate"])
        if rec is None:
            todo.append(k)
            continue
        check_replay(journal, rec, mesh, seeds)
        got[k] = rec
        if on_done:
            on_done()

    def write(rec: dict) -> None:
        journal.append(rec)
        got[todo[len(order.written)]] = rec
        if on_done:
            on_done()

    order = InOrder(write)

    def finish(i: int, result) -> None:
        base, mesh = shapes[todo[i]]
        order.done(i, evaluation_record({**base, "mesh_hash": mesh_hash(mesh.vertices, mesh.faces)}, result, ci))

    if todo:
        evaluator.evaluate_each([shapes[k][1] for k in todo], seeds, finish)
    return got


def descend(journal: Journal, chains: list[Chain], evaluator, seeds: list[int], test: PairedTest, ci: str = "auto",
            validity=None, nominal: trimesh.Trimesh | None = None, on_level=None) -> dict[int, list[dict]]:
    """Test each chain's levels in order, stopping a chain at its first level not confirmed (the fixed-sequence
    procedure); one evaluator call per step holds the next level of every chain still going, its trials in
    rounds (``test``'s race rule). Levels already journaled (``iteration``: the chain's key, ``candidate``: the
    level, 1 first) are replayed. A level ``validity(nominal, mesh)`` refuses is journaled unsimulated and
    ends its chain. Returns each chain's records by key."""
    done: dict[int, list[dict]] = {c.key: [] for c in chains}
    active = list(chains)
    while active:
        step = [(c, len(done[c.key]) + 1) for c in active if len(done[c.key]) < len(c.levels)]
        run = []
        for chain, j in step:
            fields, mesh = chain.levels[j - 1]
            rec = journal.get(chain.key, j)
            if rec is not None:
                check_replay(journal, rec, mesh, seeds)
                done[chain.key].append(rec)
                if on_level:
                    on_level()
            else:
                run.append((chain, j, fields, mesh))
        _run_step(journal, run, evaluator, seeds, test, ci, validity, nominal, done, on_level)
        active = [c for c, _ in step if done[c.key][-1]["confirmed"]]
    return done


def _run_step(journal: Journal, run: list, evaluator, seeds: list[int], test: PairedTest, ci: str, validity,
              nominal, done: dict, on_level) -> None:
    """Score one step's levels in one evaluator call; journal them in order as each is decided."""
    def write(rec: dict) -> None:
        journal.append(rec)
        done[rec["iteration"]].append(rec)
        if on_level:
            on_level()

    order = InOrder(write)
    simulate = []
    for k, (chain, j, fields, mesh) in enumerate(run):
        checks = validity(nominal, mesh) if validity is not None else {"valid": True}
        base = {"iteration": chain.key, "candidate": j, **fields, "mesh_hash": mesh_hash(mesh.vertices, mesh.faces),
                "validity": checks}
        if checks["valid"]:
            simulate.append((k, base, mesh))
        else:  # an implausible level is no answer: its chain ends here
            order.done(k, {**base, "score": float("nan"), "trials": [], "confirmed": False, "stopped": "implausible"})

    def finish(i: int, result) -> None:
        k, base, _ = simulate[i]
        rec = evaluation_record(base, result, ci)
        order.done(k, {**rec, "stopped": (result.info.get("race") or {}).get("stopped"),
                       **test.verdict(trial_scores(result))})

    if simulate:
        evaluator.evaluate_each([m for _, _, m in simulate], seeds, finish, race=test if test.at else None)
