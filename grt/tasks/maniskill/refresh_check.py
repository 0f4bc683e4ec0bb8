"""Check a task's refresh (the stale-nominal fix) from outside GRT's tests: :func:`check_refresh`.

For each attribute the task's ``refresh`` sets, it reads the env's value three ways, on one seeded episode:
with the stock actor (the env's own number), with the stock actor's geometry swapped in (a right refresh gives
the stock number back, to < 1e-6 m) and with that geometry scaled (the number should follow the size)::

    from grt.tasks.maniskill.refresh_check import check_refresh
    for row in check_refresh("my_conf/task/my_task.yaml", scale=1.3):   # or a shipped task: "stack_cube"
        print(row)

A refresh that is right passes both: ``nominal_error_m`` below 1e-6, and ``scaled`` the size a candidate of
that scale has (a refresh that returns the stock number for every candidate fails the second). The values are
read at the episode's start: a refresh that depends on how the object rests (LiftPegUpright's
``peg_half_length`` is its origin's height as it rests now, and the peg lies at the start) gives the stock
number only in the pose its success check holds in.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from grt import CONF_DIR
from grt.config.records import resolved
from grt.tasks.base import TaskInputError


def session_settings(task: str | Path | dict) -> dict:
    """The ``session`` settings of a task: a shipped task's name, a task YAML's path, or a task config dict."""
    if isinstance(task, dict):
        session = resolved(task)["session"]
    else:
        path = Path(task) if str(task).endswith((".yaml", ".yml")) else Path(CONF_DIR) / "task" / f"{task}.yaml"
        if not path.is_file():
            raise TaskInputError(f"{task}: no such task YAML (a shipped task's name, or the path of yours)")
        session = resolved(path)["session"]
    return {k: v for k, v in session.items() if k not in ("_target_", "policy")}


def check_refresh(task: str | Path | dict, scale: float | tuple = 1.3, seed: int = 0) -> list[dict]:
    """One row per attribute the task's refresh sets: ``attribute``, ``stock``, ``nominal_swap``, ``scaled``
    (flat lists of numbers: a ``Pose`` as its position and quaternion) and ``nominal_error_m`` (the largest
    difference of the nominal swap's value from the stock one). ``[]`` when the task has no refresh.

    Args:
        task: a shipped task's name, the path of a task YAML, or a task config (with ``session``).
        scale: the factor (or per-axis factors) of the scaled candidate, about the actor's origin (as the env
            would build a bigger stock actor).
        seed: the episode the values are read on.
    """
    from grt.tasks.maniskill.session import ManiSkillSession
    from grt.tasks.maniskill.swap import _numbers, refreshed

    session = ManiSkillSession(policy=None, **session_settings(task))
    try:
        swap, env = session.swap, session.unwrapped
        if swap.refresh is None:
            return []
        nominal = session.frame.mesh_to_grt(swap.reference)

        def values(mesh, names=None) -> dict:
            session.load_object(mesh, None if mesh is None else [np.asarray(mesh.convex_hull.vertices)])
            session.reset(seed, rebuild=True)
            names = names or list(refreshed(swap.refresh, env, swap))
            return {k: np.asarray(_numbers(getattr(env, k)), np.float64).ravel() for k in names}

        same = values(nominal)
        stock = values(None, list(same))
        scaled_mesh, offset = nominal.copy(), np.asarray(session.frame.offset, np.float64)
        factors = np.broadcast_to(np.asarray(scale, np.float64), (3,))
        scaled_mesh.vertices = (nominal.vertices + offset) * factors - offset  # about the actor's origin
        bigger = values(scaled_mesh, list(same))
        return [{"attribute": k, "stock": stock[k].tolist(), "nominal_swap": same[k].tolist(),
                 "scaled": bigger[k].tolist(), "nominal_error_m": float(np.abs(same[k] - stock[k]).max())}
                for k in same]
    finally:
        session.close()
