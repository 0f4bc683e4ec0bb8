"""Shrink each confirmed CrashShape to the smallest size whose drop is still confirmed (``budget.shrink``).

A CrashShape is its handle displacements ``theta``; ``alpha * theta`` for ``alpha`` in (0, 1] is a path of
shapes from the nominal object (0) to the CrashShape (1). The search tells a user *that* a shape breaks the
policy; the smallest ``alpha`` whose drop is still confirmed tells *how little* change does.

The procedure, per confirmed CrashShape: the levels ``alpha = r, r^2, r^3, ...`` (``budget.shrink_ratio``
``r``, down to ``budget.shrink_min_alpha``) are tested in that fixed order, each against the nominal object on
``budget.confirm_trials`` fresh episodes by the sequential paired test of :mod:`grt.sequential` (a level's
trials stop as soon as its answer is clear), and the shrink stops at the first level not confirmed. The
smallest ``alpha`` is the last confirmed level (1: the CrashShape itself, confirmed by :mod:`grt.confirm`).
Testing a fixed sequence and stopping at the first non-rejection keeps the probability of confirming any
level that does not truly drop within the level of one test (the fixed-sequence principle), with no
assumption that the drop grows with ``alpha``; each test's level is the run's significance level divided by
the number of shapes shrunk, so the smallest shape over all of them is covered too (Bonferroni).

The episodes are fresh once more: disjoint from the search's and from the confirmation's (on which the shapes
were chosen and confirmed: a chance confirmation there would carry down the ladder, the nearby shapes
failing on the same episodes), so the nominal object is scored on them first. Every evaluation is journaled
in ``shrink-<n>.jsonl`` (``iteration`` 0: the nominal object; then the CrashShape's rank, ``candidate``: the
level), so a shrink interrupted by Ctrl-C resumes where it stopped; the decisions replay from the journal.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from grt.confirm import ALPHA, fresh_seeds
from grt.geometry.complexity import angular_deficit_entropy
from grt.geometry.quality import shape_change
from grt.journal import Journal
from grt.optimizers.smoothness import smoothness_score
from grt.sequential import TEST, Chain, PairedTest, descend, score_shapes

_STREAM = 0x73687266  # "shrf": the shrink's fresh seeds, apart from the search's and the confirmation's


@dataclass(frozen=True)
class ShrinkSettings:
    """``budget.shrink_ratio``, ``budget.shrink_min_alpha``, ``budget.shrink_rounds``."""

    ratio: float = 0.7
    min_alpha: float = 0.05
    rounds: int = 8

    def ladder(self) -> list[float]:
        """The levels tested, largest first: ``ratio^j`` for ``j = 1, 2, ...`` while >= ``min_alpha``."""
        if not 0 < self.ratio < 1 or not 0 < self.min_alpha < 1:
            raise ValueError(f"shrink ratio and min_alpha must be in (0, 1), got {self.ratio}, {self.min_alpha}")
        count = int(math.floor(math.log(self.min_alpha) / math.log(self.ratio) + 1e-9))
        return [round(self.ratio ** j, 6) for j in range(1, count + 1)]

    def fields(self) -> dict:
        return {"ratio": self.ratio, "min_alpha": self.min_alpha, "rounds": self.rounds}


@dataclass(frozen=True)
class ShrinkShape:
    """A confirmed CrashShape to shrink: its rank, journal position, ``theta`` ``(H, 3)`` (unit cube) and its
    confirmation score with interval over ``trials`` episodes (the curve's point at ``alpha = 1``)."""

    rank: int
    iteration: int
    candidate: int
    theta: np.ndarray
    score: float
    ci95: tuple[float, float]
    trials: int


def displacement(nominal: trimesh.Trimesh, vertices: np.ndarray) -> dict:
    """How far ``vertices`` (the nominal's order, meters) are from the nominal object's.

    Returns:
        ``largest_mm`` (the surface point that moved most), ``mean_mm`` (area-weighted over the surface),
        and both as a fraction of the object's bounding-box diagonal (``largest_frac``, ``mean_frac``).
    """
    v0 = np.asarray(nominal.vertices, np.float64)
    moved = np.linalg.norm(np.asarray(vertices, np.float64) - v0, axis=1)
    faces = np.asarray(nominal.faces)
    weights = np.bincount(faces.ravel(), np.repeat(np.asarray(nominal.area_faces) / 3.0, 3), minlength=len(v0))
    diagonal = float(np.linalg.norm(np.ptp(v0, axis=0)))
    largest, mean = float(moved.max()), float(np.average(moved, weights=weights))
    return {"largest_mm": round(largest * 1000, 4), "mean_mm": round(mean * 1000, 4),
            "largest_frac": round(largest / diagonal, 6), "mean_frac": round(mean / diagonal, 6)}


def size_record(deformer, theta: np.ndarray) -> dict:
    """What a shape ``theta`` ``(H, 3)`` is, in sizes: :func:`displacement`, the Smoothness Score (mean handle
    displacement, mm) and the equivalent of the paper's σ (the root mean square of ``theta``'s coordinates,
    unit-cube units: the paper's σ = 0.001 is the standard deviation of one step of them)."""
    theta = np.asarray(theta, np.float64)
    out = displacement(deformer.mesh, deformer.vertices(theta))
    out["smoothness_mm"] = round(float(smoothness_score(theta, deformer.meters_per_unit)) * 1000, 4)
    out["sigma_equivalent"] = round(float(np.sqrt(np.mean(theta ** 2))), 6)
    return out


def shrink(run_dir: Path, shapes: list[ShrinkShape], deformer, evaluator, seeds: list[int],
           settings: ShrinkSettings, binary: bool = True, ci: str = "auto", validity: Callable | None = None,
           on_level: Callable[[], None] | None = None) -> dict:
    """Find each shape's smallest confirmed ``alpha`` (see the module doc); journaled, resumable.

    Args:
        run_dir: the run folder (gets ``shrink-<len(seeds)>.jsonl``).
        shapes: the confirmed CrashShapes, rank 1 first.
        deformer: the run's :class:`grt.geometry.deform.ShapeDeformer`.
        evaluator: the run's evaluator (still open); its ``evaluate_each(..., race=)`` runs the rounds.
        seeds: fresh episode seeds (:func:`shrink_seeds`); the nominal object is scored on them first.
        settings: the ladder and rounds.
        binary: the task's score is a success rate (else every level runs all its episodes).
        ci: the task's interval method.
        validity: ``(nominal, mesh) -> {"valid": bool, ...}``; an implausible level is not simulated and ends
            its shape's shrink.
        on_level: called as the nominal object and each level are done (a progress bar).

    Returns:
        ``summary.json``'s ``shrink`` block: the test, its levels, the seeds, the nominal object's score on them,
        ``trials_used`` and per shape (rank first) ``alpha`` (smallest confirmed), its sizes
        (:func:`size_record`), ``delta_complexity``, ``validity``, ``shape_change``, the CrashShape's own sizes
        (``full``) and ``curve`` (``alpha`` -> score, interval, trials, decision; 0: the nominal object on the
        shrink's episodes, 1: the CrashShape on the confirmation's).
    """
    ladder = settings.ladder()
    journal = Journal(Path(run_dir) / f"shrink-{len(seeds)}.jsonl")
    nominal = score_shapes(journal, [({"iteration": 0, "candidate": 0, "alpha": 0.0}, deformer.mesh)], evaluator,
                           seeds, ci, on_done=on_level)[0]
    level_alpha = ALPHA / max(1, len(shapes))
    test = PairedTest(tuple(t["score"] for t in nominal["trials"]), level_alpha, settings.rounds, binary)
    chains = [Chain(s.rank, [({"alpha": a, "shape": [s.iteration, s.candidate]}, deformer.meshes(a * s.theta)[0])
                             for a in ladder]) for s in shapes]
    levels = descend(journal, chains, evaluator, seeds, test, ci, validity, deformer.mesh, on_level)
    entropy0 = angular_deficit_entropy(deformer.mesh)
    out = [_shape_result(s, levels[s.rank], deformer, nominal, entropy0, validity) for s in shapes]
    used = len(nominal["trials"]) + sum(len(r["trials"]) for v in levels.values() for r in v)
    return {"test": TEST, "alpha": ALPHA, "level_alpha": level_alpha, **settings.fields(), "ladder": ladder,
            "trials": len(seeds), "seeds": seeds, "s0": nominal["score"], "s0_ci95": nominal["ci95"],
            "trials_used": used, "shapes": out}


def shrink_seeds(seed: int, n: int, search_seeds: list[int], confirm_seeds: list[int]) -> list[int]:
    """The shrink's ``n`` fresh episode seeds, disjoint from the search's and the confirmation's."""
    return fresh_seeds(seed, n, [*search_seeds, *confirm_seeds], _STREAM)


def _shape_result(shape: ShrinkShape, records: list[dict], deformer, nominal: dict, entropy0: float,
                  validity) -> dict:
    """One shape's record: its smallest confirmed level, sizes, complexity, checks and curve."""
    confirmed = [r for r in records if r["confirmed"]]
    alpha = confirmed[-1]["alpha"] if confirmed else 1.0
    theta = alpha * shape.theta
    mesh = deformer.meshes(theta)[0]
    curve = [{"alpha": 0.0, "score": nominal["score"], "ci95": nominal["ci95"], "trials": len(nominal["trials"]),
              "confirmed": None, "stopped": None}]
    curve += [{"alpha": r["alpha"], "score": r["score"], "ci95": r.get("ci95"), "trials": len(r["trials"]),
               "confirmed": r["confirmed"], "stopped": r.get("stopped"), "p_value": r.get("p_value")}
              for r in sorted(records, key=lambda r: r["alpha"])]
    curve.append({"alpha": 1.0, "score": shape.score, "ci95": list(shape.ci95), "trials": shape.trials,
                  "confirmed": True, "stopped": None, "episodes": "confirmation"})
    return {"rank": shape.rank, "iteration": shape.iteration, "candidate": shape.candidate, "alpha": alpha,
            "levels_tested": len(records), "trials_used": sum(len(r["trials"]) for r in records),
            **size_record(deformer, theta),
            "delta_complexity": round(angular_deficit_entropy(mesh) - entropy0, 5),
            "validity": validity(deformer.mesh, mesh) if validity is not None else None,
            **shape_change(deformer.mesh, mesh), "full": size_record(deformer, shape.theta), "curve": curve}


def smallest_mesh(deformer, shape_theta: np.ndarray, alpha: float) -> trimesh.Trimesh:
    """The shrunk shape's mesh (meters, the nominal's vertex order): ``alpha * theta`` deformed."""
    return deformer.meshes(alpha * np.asarray(shape_theta, np.float64))[0]


def save_smallest(run_dir: Path, entries: list[dict], block: dict, deformer, thetas: dict) -> None:
    """Write each shrunk CrashShape beside its CrashShape (``<stem>_smallest.stl`` / ``.obj``, meters) and add
    its figures to the CrashShape's entry of ``summary.json`` (``smallest``).

    Args:
        run_dir: the run folder.
        entries: ``summary.json``'s ``crashshapes`` entries (``file``: ``crashshapes/<stem>.stl``); changed in place.
        block: :func:`shrink`'s result.
        deformer: the run's deformer.
        thetas: ``{(iteration, candidate): theta}`` of the journal.
    """
    from grt.fileio import atomic_path

    by_shape = {(s["iteration"], s["candidate"]): s for s in block["shapes"]}
    for entry in entries:
        shape = by_shape.get((entry["iteration"], entry["candidate"]))
        if shape is None:
            continue
        stem = Path(entry["file"]).with_suffix("")
        mesh = smallest_mesh(deformer, thetas[entry["iteration"], entry["candidate"]], shape["alpha"])
        for ext in ("stl", "obj"):
            with atomic_path(run_dir / f"{stem}_smallest.{ext}") as tmp:
                mesh.export(tmp, file_type=ext)
        keep = ("alpha", "largest_mm", "mean_mm", "largest_frac", "mean_frac", "smoothness_mm", "sigma_equivalent",
                "delta_complexity")
        entry["smallest"] = {**{k: shape[k] for k in keep}, "file": f"{stem}_smallest.stl"}
