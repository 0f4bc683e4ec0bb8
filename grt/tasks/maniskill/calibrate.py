"""Calibration of a ManiSkill task: the nominal swap against the stock env, seed for seed.

The swap replaces the stock actor's primitives (a PhysX box, sphere, ...) by convex parts of the nominal
mesh: the same shape, mass and frame, but not the same contact geometry to the last digit (a convex box
is not a box primitive; a sphere becomes a polyhedron). :func:`calibrate` runs the same policy on the same
seeds twice in one session, once with the stock actor and once with the nominal mesh swapped in (and the
task's refresh on), and reports per-seed agreement of the outcomes, the two success rates, and the swapped
actor's mass and extents against the stock one's, so a user sees how far the swap itself moves a task
before any deformation is scored.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import trimesh


def _mass(actor) -> float:
    from sapien import physx

    body = actor._objs[0].find_component_by_type(physx.PhysxRigidDynamicComponent)
    return float(body.mass) if body is not None else float("nan")


def _geometry(session) -> dict:
    """Mass (kg) and extents (m, actor frame) of the actor now in the session's scene (sub-scene 0)."""
    build = session.swap.build_of(0)
    hull = session.swap.hull(0)
    return {"mass_kg": _mass(build.actor), "extents_m": np.ptp(hull, axis=0).round(6).tolist()}


def calibrate(session, mesh: trimesh.Trimesh, parts: list[np.ndarray], seeds: list[int],
              on_trial: Callable[[], None] | None = None) -> dict:
    """Run ``seeds`` with the stock actor, then with ``mesh`` (GRT's frame) and ``parts`` swapped in.

    Args:
        session: a :class:`grt.tasks.maniskill.session.ManiSkillSession` with its policy.
        mesh, parts: the nominal object (``object: actor``) and its convex parts (m).
        seeds: episode seeds.
        on_trial: called after each trial (progress).

    Returns:
        ``{"seeds", "stock": {...}, "swap": {...}, "agreement", "agree": [bool per seed], "mass_ratio",
        "extents_ratio"}``: per run its ``success_rate``, ``modes`` (per seed), ``scores``, ``mass_kg``,
        ``extents_m``, ``wall_s``.
    """
    runs = {}
    for name, obj in (("stock", None), ("swap", (mesh, parts))):
        session.load_object(*(obj or (None, None)))
        start = time.perf_counter()
        outcomes = []
        for seed in seeds:
            outcomes.append(session.run_trial(int(seed)))
            if on_trial is not None:
                on_trial()
        runs[name] = {"success_rate": float(np.mean([o.success for o in outcomes])),
                      "score": float(np.mean([o.score for o in outcomes])),
                      "modes": [o.mode for o in outcomes], "scores": [round(o.score, 6) for o in outcomes],
                      **_geometry(session), "wall_s": round(time.perf_counter() - start, 3)}
    agree = [a == b for a, b in zip(runs["stock"]["modes"], runs["swap"]["modes"], strict=True)]
    ext_s, ext_w = np.asarray(runs["stock"]["extents_m"]), np.asarray(runs["swap"]["extents_m"])
    return {"seeds": [int(s) for s in seeds], **runs, "agree": agree, "agreement": float(np.mean(agree)),
            "mass_ratio": round(runs["swap"]["mass_kg"] / runs["stock"]["mass_kg"], 6),
            "extents_ratio": (ext_w / np.maximum(ext_s, 1e-12)).round(6).tolist()}
