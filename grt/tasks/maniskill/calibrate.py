"""Calibration of a ManiSkill task: the nominal swap against the stock env, seed for seed, and where they part.

The swap replaces the stock actor's primitives (a PhysX box, sphere, ...) by convex parts of the nominal
mesh: the same shape, mass and frame, but not the same contact geometry to the last digit (a convex box
is not a box primitive; a sphere becomes a polyhedron). :func:`calibrate` runs the same policy on the same
seeds twice in one session, once with the stock actor and once with the nominal mesh swapped in (and the
task's refresh on), and reports per-seed agreement of the outcomes, the two success rates, and the swapped
actor's mass and extents against the stock one's, so a user sees how far the swap itself moves a task
before any deformation is scored. :func:`fidelity` replays episodes open-loop on both
(:mod:`grt.tasks.maniskill.fidelity`): where the copy parts from the stock actor, with or without a policy.

A calibration that cannot compare is refused (:class:`CalibrationError`, one line naming the side that
failed): the stock actor's scene does not build or the policy fails on it (a trial of the stock actor ends in
``sim_error``), or the nominal swap does not build.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import trimesh

from grt.tasks.base import TaskInputError
from grt.tasks.maniskill import fidelity as fid
from grt.tasks.maniskill.probe import push


class CalibrationError(TaskInputError):
    """A calibration that cannot run: the message names the side that failed (stock or swap) and why."""


def _mass(actor) -> float:
    from sapien import physx

    body = actor._objs[0].find_component_by_type(physx.PhysxRigidDynamicComponent)
    return float(body.mass) if body is not None else float("nan")


def _geometry(session) -> dict:
    """Mass (kg) and extents (m, actor frame) of the actor now in the session's scene (sub-scene 0)."""
    build = session.swap.build_of(0)
    hull = session.swap.hull(0)
    return {"mass_kg": _mass(build.actor), "extents_m": np.ptp(hull, axis=0).round(6).tolist()}


def load(session, side: str, candidate: tuple | None, seed: int) -> None:
    """Load the stock actor (``candidate=None``) or ``(mesh, parts)`` and build its scene once.

    Raises:
        CalibrationError: the scene does not build (names ``side``).
    """
    session.load_object(*(candidate or (None, None)))
    try:
        session.reset(int(seed), rebuild=True)
    except TaskInputError as err:
        raise CalibrationError(f"calibration cannot run: the {side} fails to build ({err})") from None
    except Exception as err:  # noqa: BLE001 - a scene that does not build, whatever the reason
        raise CalibrationError(f"calibration cannot run: the {side} fails to build ({type(err).__name__}: "
                               f"{str(err).splitlines()[0] if str(err) else ''})") from None


def _check_stock(outcome, seed: int) -> None:
    """A stock trial that ended in ``sim_error``: the policy (or the env) fails before any swap."""
    if outcome.mode == "sim_error":
        why = str(outcome.info.get("error", "")).splitlines()[0] if outcome.info.get("error") else "no error message"
        raise CalibrationError(f"calibration cannot run: the policy fails on the stock actor (seed {seed} ended in "
                               f"sim_error: {why}); fix the policy or the task before comparing the swap")


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

    Raises:
        CalibrationError: the stock scene or the swap does not build, or a stock trial ends in ``sim_error``.
    """
    runs = {}
    for name, side, obj in (("stock", "stock env", None), ("swap", "nominal swap", (mesh, parts))):
        load(session, side, obj, seeds[0])
        start = time.perf_counter()
        outcomes = []
        for seed in seeds:
            outcomes.append(session.run_trial(int(seed)))
            if name == "stock":
                _check_stock(outcomes[-1], int(seed))
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


def _episode(session, source: str, seed: int, actions: np.ndarray | None) -> fid.Episode:
    """The stock episode of ``seed`` to replay: the policy's, GRT's push, or ``actions`` ``(T, A)`` from a file."""
    if actions is not None:
        return fid.Episode(int(seed), 1, [np.asarray(a, np.float32)[None] for a in actions], [])
    episode = fid.record(session, seed, push if source == "push" else None)
    if source == "policy" and not episode.actions:
        raise CalibrationError(f"calibration cannot run: the policy took no step on the stock actor (seed {seed}); "
                               "fidelity.actions=push or a recorded action file replays without it")
    return episode


def fidelity(session, mesh: trimesh.Trimesh, parts: list[np.ndarray], source: str, seeds: list[int],
             actions: np.ndarray | None = None, on_episode: Callable[[], None] | None = None) -> dict:
    """Replay one stock episode per seed open-loop on the stock actor and on the nominal swap.

    Args:
        source: ``policy`` (the session's policy drives the stock episode), ``push`` (GRT's scripted push,
            :mod:`grt.tasks.maniskill.probe`) or ``file`` (``actions``, ``(T, A)``, replayed from ``seeds[0]``).

    Returns:
        ``{"source", "episodes": [per seed: fidelity.check's record], "median": {swap and nudge's max_mm,
        max_deg}, "actions": [per seed: (T, A) the actions replayed]}``.
    """
    load(session, "nominal swap", (mesh, parts), seeds[0])
    load(session, "stock env", None, seeds[0])
    episodes, replayed = [], []
    for seed in seeds:
        session.load_object(None, None)
        episode = _episode(session, source, int(seed), actions)
        episodes.append(fid.check(session, (mesh, parts), episode, source))
        replayed.append(np.concatenate([np.asarray(a, np.float32).reshape(1, -1) for a in episode.actions]))
        if on_episode is not None:
            on_episode()
    median = {f"{k}_{m}": round(float(np.median([e[k][m] for e in episodes])), 3)
              for k in ("swap", "nudge") for m in ("max_mm", "max_deg")}
    return {"source": source, "episodes": episodes, "median": median, "actions": replayed}
