"""Confirm a run's CrashShapes on episodes the search never saw (``budget.confirm_trials``).

A search keeps the lowest of many noisy scores. With a policy whose outcome changes with any change of
its input (a learned grasp network re-draws its grasp when the depth images change by a fraction of a
millimetre), the lowest of 30 scores of 8 trials each is low by luck alone, whatever the geometry: the
winner's curse. Confirmation re-scores the nominal object and each of the run's ``top_k`` CrashShapes on
``confirm_trials`` fresh episode seeds (disjoint from the search's, shared among the shapes: common random
numbers) and tests each CrashShape against the nominal object episode by episode: a one-sided paired
sign-flip permutation test of the per-episode score differences (binary and continuous scores alike; for
success rates it is the exact one-sided McNemar test on the discordant episodes), Holm-corrected over the
``k`` shapes, and gives each drop a paired 95% interval (:func:`paired_drop_interval`). The headline, ``confirmed_final_drop``, is the relative drop of the
**rank-1** CrashShape on the fresh episodes: the search's own choice, not the best of ``k`` chosen again
(which would re-introduce the selection it corrects).

Every confirmation evaluation is journaled in ``confirm-<n>.jsonl`` (one file per trial count, the same
crash-safe, checksummed journal as the search's), so a killed confirmation resumes where it stopped.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from grt.geometry.mesh import mesh_hash
from grt.journal import InOrder, Journal, JournalError
from grt.metrics import score_interval

ALPHA = 0.05
PERMUTATIONS = 20_000
DRAWS = 20_000  # posterior draws of a paired drop's interval
INTERVAL = ("95% interval of the paired drop: Dirichlet posterior of the (nominal, shape) outcome pairs, Jeffreys "
            "prior (success rates); Bayesian bootstrap of the episodes (continuous scores)")
TEST = "one-sided paired sign-flip permutation test of per-episode differences, Holm over the k shapes"
_STREAM = 0x636F6E66  # "conf": the fresh seeds' own random stream, apart from the search's


# The object's stance when the policy looked (trial info of the grasp task), and what counts as not at rest.
STANCE = ("tilt_deg", "spin_dps")
SPIN_DPS, TILT_DEG = 30.0, 45.0


def confirm_seeds(seed: int, n: int, exclude: list[int]) -> list[int]:
    """``n`` episode seeds drawn from ``seed``'s confirmation stream, none of them in ``exclude``.

    The same ``(seed, n, exclude)`` always gives the same seeds, and the seeds for ``n`` are the first
    ``n`` of those for any larger count.
    """
    if n < 1:
        raise ValueError(f"confirmation needs >= 1 trial, got {n}")
    return fresh_seeds(seed, n, exclude, _STREAM)


def fresh_seeds(seed: int, n: int, exclude: list[int], stream: int) -> list[int]:
    """``n`` distinct episode seeds of ``seed``'s ``stream`` (a constant of the caller: the confirmation's, the
    shrink's, a profile's), none in ``exclude``; the seeds for ``n`` are the first ``n`` of those for any larger
    count."""
    rng, taken, out = np.random.default_rng([seed, stream]), set(exclude), []
    while len(out) < n:
        s = int(rng.integers(0, 2**31 - 1))
        if s not in taken:
            taken.add(s)
            out.append(s)
    return out


def paired_drop_p(shape: np.ndarray, nominal: np.ndarray, permutations: int = PERMUTATIONS,
                  seed: int = 0) -> float:
    """One-sided p-value that ``shape`` scores lower than ``nominal`` on the same episodes.

    Under the null hypothesis (the shape does not change the policy's success) each per-episode
    difference is as likely positive as negative, so the observed mean difference is compared with the
    mean differences of random sign flips (exact over all flips when there are at most 16 non-zero
    differences). Episodes where either score is NaN (a simulator error) are left out.

    Returns:
        p in (0, 1]; 1.0 without any non-zero difference.
    """
    d = np.asarray(shape, np.float64) - np.asarray(nominal, np.float64)
    d = d[np.isfinite(d) & (d != 0)]
    if d.size == 0:
        return 1.0
    observed = d.sum()
    if d.size <= 16:  # every sign pattern: exact
        signs = 1 - 2 * ((np.arange(2**d.size)[:, None] >> np.arange(d.size)) & 1)
        sums = signs @ d
        return float(np.mean(sums <= observed + 1e-12))
    rng = np.random.default_rng(seed)
    sums = (rng.choice((-1.0, 1.0), size=(permutations, d.size)) * d).sum(axis=1)
    return float((1 + np.sum(sums <= observed + 1e-12)) / (1 + permutations))


def paired_drop_interval(shape: np.ndarray, nominal: np.ndarray, draws: int = DRAWS,
                         seed: int = 0) -> tuple[float, float]:
    """95% interval of the relative drop ``1 - mean(shape) / mean(nominal)`` on the same episodes.

    Paired, and never degenerate at 0 or 1 with few episodes: success rates by the Dirichlet posterior of the
    four (nominal, shape) outcome pairs with a Jeffreys prior (1/2 each; 32 episodes where the nominal always
    succeeds and the shape never does give about [0.89, 1.00], not [1, 1]); continuous scores by the
    Bayesian bootstrap of the episodes (Dirichlet(1, ..., 1) weights). Episodes where either score is NaN
    are left out; seeded, so a summary is the same every time.

    Returns:
        ``(low, high)``, fractions of the nominal's score; NaN without episodes.
    """
    a, b = np.asarray(nominal, np.float64), np.asarray(shape, np.float64)
    keep = np.isfinite(a) & np.isfinite(b)
    a, b = a[keep], b[keep]
    if a.size == 0:
        return (float("nan"), float("nan"))
    rng = np.random.default_rng([seed, _STREAM, 1])
    if np.all(np.isin(a, (0.0, 1.0))) and np.all(np.isin(b, (0.0, 1.0))):
        cells = np.array([np.sum((a == 1) & (b == 1)), np.sum((a == 1) & (b == 0)),
                          np.sum((a == 0) & (b == 1)), np.sum((a == 0) & (b == 0))], np.float64)
        w = rng.dirichlet(cells + 0.5, size=draws)
        nom, shp = w[:, 0] + w[:, 1], w[:, 0] + w[:, 2]
    else:
        w = rng.dirichlet(np.ones(a.size), size=draws)
        nom, shp = w @ a, w @ b
    ok = nom > 0
    if not np.any(ok):
        return (float("nan"), float("nan"))
    low, high = np.percentile(1.0 - shp[ok] / nom[ok], [2.5, 97.5])
    return (float(low), float(high))


def holm(p_values: list[float]) -> list[float]:
    """Holm-Bonferroni adjusted p-values (same order as given)."""
    p = np.asarray(p_values, np.float64)
    order = np.argsort(p, kind="stable")
    adjusted = np.empty_like(p)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(p) - rank) * p[i]))
        adjusted[i] = running
    return adjusted.tolist()


def confirm(run_dir: Path, best: list[dict], meshes: list[trimesh.Trimesh], nominal: trimesh.Trimesh, evaluator,
            search_seeds: list[int], seed: int, trials: int, ci: str = "auto",
            on_evaluated: Callable[[], None] | None = None) -> dict:
    """Score the nominal object and each CrashShape on ``trials`` fresh episodes; test each drop.

    Args:
        run_dir: the run folder (gets ``confirm-<trials>.jsonl``).
        best: the CrashShapes' journal records, rank 1 first (:func:`grt.outputs.crash_records`).
        meshes: their meshes, in the same order.
        nominal: the nominal object.
        evaluator: the run's evaluator (still open).
        search_seeds: the episodes of the search (excluded from the fresh ones).
        seed: ``budget.seed``.
        trials: fresh episodes per shape.
        ci: the task's interval method for the scores' ``ci95``.
        on_evaluated: called after each shape is scored or replayed from the journal (a progress bar).

    Returns:
        The ``confirm`` block of ``summary.json``: ``trials, seeds, s0, s0_ci95, test, alpha, shapes``
        (per CrashShape: ``rank, iteration, candidate, search_score, score, ci95, drop, p_value, p_holm,
        confirmed``), ``confirmed_final_drop`` and ``confirmed`` (how many shapes passed the test).
    """
    start = time.perf_counter()
    seeds = confirm_seeds(seed, trials, search_seeds)
    journal = Journal(Path(run_dir) / f"confirm-{trials}.jsonl")

    # the nominal object first, then the CrashShapes by rank; those not in the journal are scored in one
    # evaluator call and journaled in this order as each finishes
    todo = [(0, 0, nominal)] + [(rec["iteration"], rec["candidate"], mesh)
                                for rec, mesh in zip(best, meshes, strict=True)]
    got: list[dict | None] = [None] * len(todo)
    missing = []
    for k, (t, i, mesh) in enumerate(todo):
        rec = journal.get(t, i)
        if rec is None:
            missing.append(k)
        elif rec["mesh_hash"] != mesh_hash(mesh.vertices, mesh.faces) or [tr["seed"] for tr in rec["trials"]] != seeds:
            raise JournalError(f"{journal.path}: the confirmation of iteration {t} candidate {i} was made for "
                               "another shape or other episodes; delete the file to confirm again")
        else:
            got[k] = rec
            if on_evaluated:
                on_evaluated()
    def write(rec: dict) -> None:
        got[missing[len(order.written)]] = rec
        journal.append(rec)
        if on_evaluated:
            on_evaluated()

    order = InOrder(write)

    def finish(j: int, result) -> None:
        t, i, mesh = todo[missing[j]]
        order.done(j, {"iteration": t, "candidate": i, "score": float(result.score),
                       "mesh_hash": mesh_hash(mesh.vertices, mesh.faces), "ci95": list(result.ci95(ci)),
                       "outcomes": result.outcomes,
                       "trials": [{"seed": o.seed, "score": float(o.score) if o.mode != "sim_error" else float("nan"),
                                   "mode": o.mode, **{k: o.info[k] for k in STANCE if k in o.info}}
                                  for o in result.trials]})

    if missing:
        evaluator.evaluate_each([todo[k][2] for k in missing], seeds, finish)

    nom = got[0]
    nominal_trials = np.array([tr["score"] for tr in nom["trials"]])
    s0 = nom["score"]
    shapes = []
    for rank, (rec, shape) in enumerate(zip(best, got[1:], strict=True), start=1):
        shape_trials = np.array([tr["score"] for tr in shape["trials"]])
        shapes.append({"rank": rank, "iteration": rec["iteration"], "candidate": rec["candidate"],
                       "search_score": rec["score"], "score": shape["score"], "ci95": shape["ci95"],
                       "drop": _drop(s0, shape["score"]),
                       "drop_ci95": list(paired_drop_interval(shape_trials, nominal_trials, seed=seed)),
                       "p_value": paired_drop_p(shape_trials, nominal_trials, seed=seed),
                       "outcomes": shape["outcomes"], **unsettled(shape["trials"])})
    for shape, adjusted in zip(shapes, holm([s["p_value"] for s in shapes]), strict=True):
        shape["p_holm"] = adjusted
        shape["confirmed"] = bool(adjusted < ALPHA and shape["score"] < s0)
    valid = nominal_trials[np.isfinite(nominal_trials)]
    return {"trials": trials, "seeds": seeds, "s0": s0, "s0_ci95": list(score_interval(valid, ci)),
            "test": TEST, "alpha": ALPHA, "shapes": shapes,
            "confirmed_final_drop": shapes[0]["drop"] if shapes else None,
            "confirmed_drop_ci95": shapes[0]["drop_ci95"] if shapes else None,
            "confirmed_p": shapes[0]["p_holm"] if shapes else None,
            "interval": INTERVAL, "wall_s": round(time.perf_counter() - start, 1),
            "confirmed": sum(s["confirmed"] for s in shapes), **unsettled(nom["trials"])}


def unsettled(trials: list[dict]) -> dict:
    """``{"unsettled": n, "stance_trials": m}``: of the ``m`` trials that recorded the object's stance when the
    policy looked (the grasp task's ``tilt_deg``, ``spin_dps``), the ``n`` where it was still turning faster than
    :data:`SPIN_DPS` or had tipped past :data:`TILT_DEG` (a shape that cannot stand: every policy fails it
    alike); ``{}`` when no trial recorded it (other tasks, journals written before)."""
    seen = [t for t in trials if all(k in t for k in STANCE)]
    if not seen:
        return {}
    return {"unsettled": sum(t["spin_dps"] > SPIN_DPS or t["tilt_deg"] > TILT_DEG for t in seen),
            "stance_trials": len(seen)}


def _drop(s0: float, score: float) -> float:
    """Relative drop ``(S0 - score) / S0`` (NaN when S0 is not positive or a score is missing)."""
    if not (np.isfinite(s0) and np.isfinite(score) and s0 > 0):
        return float("nan")
    return float((s0 - score) / s0)
