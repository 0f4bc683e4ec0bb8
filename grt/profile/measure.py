"""Measure a robustness profile: success against deformation size, random and adversarial, and two margins.

On ``trials`` fresh episodes (disjoint from the run's search, confirmation and shrink episodes; the nominal
object scored on them first: S0 and its band):

* **random**: at each size of the ladder, ``shapes`` random plausible deformations (the handles' displacements
  in random directions, scaled to the size), every one on every episode; the size's score is the mean over
  all its trials. The **random margin** is the largest size up to which every size keeps its score within the
  task's crash margin of S0 (``score >= S0 (1 - crash_margin)``); its interval is the same rule applied to the
  scores' lower and upper 95% bounds.
* **adversarial**: each CrashShape direction of the run (its confirmed ones first, at most ``directions``)
  scaled to the ladder's sizes, tested from the largest size down, each size by the sequential paired test of
  :mod:`grt.sequential` against the nominal object, stopping at the first size not confirmed (the
  fixed-sequence procedure; the level divided among the directions). The **adversarial margin** is the
  smallest size at which a direction is confirmed to break the policy; the true one lies between it and the
  next smaller size of the ladder (its interval).

Every evaluation is journaled in ``profile.jsonl`` (``iteration`` 0: the nominal object, 1: the random shapes,
``100 + d``: direction ``d``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from grt.confirm import ALPHA
from grt.evaluators.base import NothingScoredError
from grt.journal import Journal
from grt.metrics import score_interval
from grt.profile import PROFILE_JOURNAL
from grt.profile.shapes import ProfileError, largest_mm, plausible_limit, plausible_shapes, scale_to_size
from grt.sequential import TEST, Chain, PairedTest, descend, score_shapes
from grt.shrink import size_record

RANDOM, DIRECTION = 1, 100  # journal iterations: the random shapes, then direction d at DIRECTION + d


@dataclass(frozen=True)
class Direction:
    """An adversarial direction: a CrashShape of the run (rank, journal position, ``theta`` ``(H, 3)``)."""

    rank: int
    iteration: int
    candidate: int
    theta: np.ndarray
    confirmed: bool | None = None


@dataclass
class Plan:
    """The shapes of a profile, made (and checked for plausibility) before any simulation."""

    sizes: list[float]
    random: list[tuple[float, list[np.ndarray], int]] = field(default_factory=list)  # size, thetas, refused
    directions: list[tuple[Direction, list[tuple[float, np.ndarray]], list[float]]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def plan(deformer, sizes: list[float], shapes: int, seed: int, directions: list[Direction], validity,
         given: bool) -> Plan:
    """Make every shape of the profile: per size ``shapes`` plausible random ones (seeded by ``seed`` and the
    size), per direction its plausible sizes (largest first).

    Raises:
        ProfileError: ``given`` sizes (the user's ladder) of which one has no plausible random shape: beyond what
            the deformer keeps plausible (a default ladder drops such a size and says so in ``notes``).
    """
    out = Plan(sizes=[])
    for size in sizes:
        rng = np.random.default_rng([seed, int(round(size * 1e4))])
        thetas, refused = plausible_shapes(deformer, size, shapes, rng, validity)
        if not thetas:
            limit = plausible_limit(deformer, size, np.random.default_rng(seed), validity)
            why = (f"{size:g} mm is beyond what the deformer keeps plausible for this object: none of {refused} random "
                   "shapes of that size passed the plausibility checks (self-intersection, folds, volume change)"
                   + (f"; random shapes stay plausible up to about {limit:g} mm" if limit else ""))
            if given:
                raise ProfileError(f"profile.sizes: {why}; give sizes up to that")
            out.notes.append(f"size dropped: {why}")
            continue
        out.sizes.append(size)
        out.random.append((size, thetas, refused))
    for d in directions:
        levels, dropped = [], []
        for size in sorted(out.sizes, reverse=True):
            theta = scale_to_size(deformer, d.theta, size)
            if validity is None or validity(deformer.mesh, deformer.meshes(theta)[0])["valid"]:
                levels.append((size, theta))
            else:
                dropped.append(size)
        out.directions.append((d, levels, dropped))
    return out


def measure(out_dir: Path, plan_: Plan, deformer, evaluator, seeds: list[int], s0_margin: float, binary: bool = True,
            ci: str = "auto", rounds: int = 8, on_done: Callable[[], None] | None = None) -> dict:
    """Simulate the profile ``plan_`` on ``seeds``; returns ``profile.json``'s measurements and margins.

    Args:
        out_dir: the profile's folder (``profile.jsonl``).
        plan_: :func:`plan`'s shapes.
        deformer: the deformer (the run's, or over the selected handles).
        evaluator: an open evaluator.
        seeds: fresh episode seeds.
        s0_margin: the task's crash margin (a fraction of S0).
        binary: the score is a success rate; ci: the task's interval method.
        rounds: rounds of the adversarial sizes' sequential test.
        on_done: called as each shape is done (a progress bar).
    """
    journal = Journal(Path(out_dir) / PROFILE_JOURNAL)
    nominal = score_shapes(journal, [({"iteration": 0, "candidate": 0, "kind": "nominal"}, deformer.mesh)],
                           evaluator, seeds, ci, on_done)[0]
    if not any(t["score"] == t["score"] for t in nominal["trials"]):
        first = nominal["trials"][0]
        raise NothingScoredError(f"every trial of the nominal object ended in sim_error (the first, seed "
                                 f"{first['seed']}: see {journal.path}), so there is no S0 to profile against")
    shapes = [({"iteration": RANDOM, "candidate": k, "kind": "random", "size_mm": size}, deformer.meshes(theta)[0])
              for k, (size, theta) in enumerate((s, t) for s, thetas, _ in plan_.random for t in thetas)]
    records = score_shapes(journal, shapes, evaluator, seeds, ci, on_done)
    thetas = [t for _, ts, _ in plan_.random for t in ts]
    random = _random_curve(plan_, records, thetas, deformer, ci)
    test = PairedTest(tuple(t["score"] for t in nominal["trials"]), ALPHA / max(1, len(plan_.directions)), rounds,
                      binary)
    chains = [Chain(DIRECTION + j, [({"kind": "adversarial", "size_mm": size, "rank": d.rank},
                                     deformer.meshes(theta)[0]) for size, theta in levels])
              for j, (d, levels, _) in enumerate(plan_.directions, start=1)]
    tested = descend(journal, chains, evaluator, seeds, test, ci, on_level=on_done)
    adversarial = [_direction(d, levels, dropped, tested[DIRECTION + j], deformer)
                   for j, (d, levels, dropped) in enumerate(plan_.directions, start=1)]
    threshold = nominal["score"] * (1 - s0_margin)
    used = sum(len(r["trials"]) for r in [nominal, *records, *(x for v in tested.values() for x in v)])
    return {"s0": nominal["score"], "s0_ci95": nominal["ci95"], "crash_margin": s0_margin, "threshold": threshold,
            "random": random, "adversarial": adversarial, "test": TEST, "alpha": ALPHA, "level_alpha": test.alpha,
            "margins": margins(random, adversarial, threshold, plan_.sizes), "trials_used": used}


def _random_curve(plan_: Plan, records: list[dict], thetas: list[np.ndarray], deformer, ci: str) -> list[dict]:
    """Per size: the pooled score over its shapes' trials with its interval, and each shape's figures."""
    out, k = [], 0
    for size, sized, refused in plan_.random:
        recs = records[k:k + len(sized)]
        pooled = [t["score"] for r in recs for t in r["trials"] if t["score"] == t["score"]]
        out.append({"size_mm": size, "score": float(np.mean(pooled)) if pooled else float("nan"),
                    "ci95": list(score_interval(pooled, ci)), "trials": len(pooled), "refused_draws": refused,
                    "shapes": [{"score": r["score"], "ci95": r["ci95"], **size_record(deformer, t)}
                               for r, t in zip(recs, thetas[k:k + len(sized)], strict=True)]})
        k += len(sized)
    return out


def _direction(d: Direction, levels: list, dropped: list[float], records: list[dict], deformer) -> dict:
    """One adversarial direction: the sizes tested (largest first) and the smallest confirmed."""
    confirmed = [r["size_mm"] for r in records if r["confirmed"]]
    return {"rank": d.rank, "iteration": d.iteration, "candidate": d.candidate, "run_confirmed": d.confirmed,
            "own_size_mm": round(largest_mm(deformer, d.theta), 3), "implausible_sizes_mm": dropped,
            "untested_sizes_mm": [s for s, _ in levels[len(records):]],
            "levels": [{"size_mm": r["size_mm"], "score": r["score"], "ci95": r.get("ci95"), "trials": len(r["trials"]),
                        "confirmed": r["confirmed"], "stopped": r.get("stopped"), "p_value": r.get("p_value")}
                       for r in records],
            "smallest_confirmed_mm": min(confirmed) if confirmed else None}


def margins(random: list[dict], adversarial: list[dict], threshold: float, sizes: list[float]) -> dict:
    """The two margins (mm) with their intervals; see the module doc.

    Returns:
        ``random_mm`` (``None``: even the smallest size drops beyond the crash margin), ``random_interval_mm``,
        ``random_beyond`` (every size kept the score: the margin is at least the largest size); ``adversarial_mm``
        (``None``: no direction confirmed at any size), ``adversarial_interval_mm`` (the next smaller size of the
        ladder, exclusive, to the margin).
    """
    def keeps(values: list[float]) -> float | None:
        kept = None
        for row, v in zip(random, values, strict=True):
            if not v >= threshold:
                break
            kept = row["size_mm"]
        return kept

    point = keeps([r["score"] for r in random])
    low, high = keeps([r["ci95"][0] for r in random]), keeps([r["ci95"][1] for r in random])
    smallest = [d["smallest_confirmed_mm"] for d in adversarial if d["smallest_confirmed_mm"] is not None]
    adv = min(smallest) if smallest else None
    below = max([s for s in sizes if adv is not None and s < adv], default=0.0)
    return {"random_mm": point, "random_interval_mm": [low or 0.0, high or 0.0],
            "random_beyond": bool(random) and point == random[-1]["size_mm"],
            "adversarial_mm": adv, "adversarial_interval_mm": [below, adv] if adv is not None else None}
