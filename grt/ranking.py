"""How a run ranks its candidates into CrashShapes: by a lower confidence bound of the drop, not the observed score.

A candidate's score is the mean of a few trials. Ranking by the observed score lets the luckiest draw win:
a candidate scored on fewer valid trials (simulator errors, a continuous score with a wide spread) reaches
an extreme mean more easily than one with more evidence. Each candidate is ranked instead by the lower end
of its drop's 95% interval, ``1 - hi / S0`` with ``hi`` the upper end of its score's interval (the task's
``ci`` method, journaled as ``ci95``): the drop it shows at least, given its own trials.

With every candidate scored on the same number of valid trials of a success rate, that order is the
observed order (Wilson's upper end rises with the count of successes); it changes where the evidence
differs. Ties are broken by the observed score, then by the earliest iteration and candidate. What removes
the winner's curse itself is confirmation on fresh episodes (:mod:`grt.confirm`), which re-scores the
top-ranked shapes on episodes the search never saw.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def drop_lower_bound(record: dict, s0: float) -> float:
    """The lower end of a candidate's drop, ``1 - hi / S0`` (``hi``: the upper end of its journaled ``ci95``;
    a record without an interval: its score). NaN without a positive ``S0`` or a score."""
    ci = record.get("ci95") or [None, None]
    hi = ci[1] if ci[1] is not None and ci[1] == ci[1] else record.get("score")
    if hi is None or not (s0 == s0 and s0 > 0) or hi != hi:
        return float("nan")
    return 1.0 - float(hi) / float(s0)


def rank_key(record: dict) -> tuple:
    """Sort key of a scored candidate, best CrashShape first: the upper end of its score's interval (the
    lower bound of its drop), then its score, iteration and candidate index."""
    ci = record.get("ci95") or [None, None]
    hi = ci[1] if ci[1] is not None and ci[1] == ci[1] else record["score"]
    return (float(hi), float(record["score"]), record["iteration"], record["candidate"])


def ranked(records: Sequence[dict]) -> list[dict]:
    """``records`` (scored candidates) in CrashShape order (:func:`rank_key`)."""
    return sorted((r for r in records if not math.isnan(float(r["score"]))), key=rank_key)
