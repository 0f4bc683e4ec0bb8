"""The stale-nominal fixes of the stock tasks: what each env's success check reads about its actor, made
true of the candidate.

Several stock envs judge success with numbers of their *nominal* actor: a candidate of another size that
did what the task asks would be judged a failure by stale numbers, and a CrashShape must never come from
the judge's own mistake. A task's ``refresh`` (``task.session.refresh``, a dotted path) is called before
every ``evaluate()`` of the env with a candidate in it and returns ``{attribute: value}``; the swap sets
them and puts the stock values back before the env loads a scene or places an episode
(:mod:`grt.tasks.maniskill.swap`), so the env's own set-up still sees its stock numbers. Each value is
computed from the geometry now in the scene (the candidate's convex parts, in the actor frame) and the
actor's pose now, so a check that depends on how the object rests (which side is down) stays right.

With the stock actor's own geometry (the nominal swap) every value equals the stock one to < 1e-6 m:
the calibration (``python -m grt.calibrate``) runs the refreshed nominal swap against the stock env.

How to check your own env: read its ``evaluate()`` (and ``_get_obs_extra``) for attributes of the actor
you swap (sizes, half lengths, offsets of a point on it); each needs a refresh like these, or a
continuous score that does not read them.
"""

from __future__ import annotations

import numpy as np

from grt.tasks.maniskill.swap import ActorSwap, _quat_matrix, depth_below, top_above


def _rotations(actor) -> list[np.ndarray]:
    """``(3, 3)`` world rotations of an actor's bodies, one per sub-scene."""
    from mani_skill.utils import common

    q = np.asarray(common.to_numpy(actor.pose.q), np.float64).reshape(-1, 4)
    return [_quat_matrix(row) for row in q]


def _scalar_or_tensor(values: list[float], device):
    """One number per sub-scene: a float for one sub-scene (the stock code mixes it into Python lists),
    else a ``(num_envs,)`` tensor."""
    import torch

    return float(values[0]) if len(values) == 1 else torch.tensor(values, dtype=torch.float32, device=device)


def push_cube(env, swap: ActorSwap) -> dict:
    """PushCube-v1 succeeds only while the cube lies on the table: ``z < cube_half_size + 5 mm``. With a
    candidate, ``cube_half_size`` is the height of its origin when it rests in its current orientation
    (the depth of its lowest point below its origin), so "lying on the table" keeps its meaning."""
    rots = _rotations(env.obj)
    return {"cube_half_size": _scalar_or_tensor([depth_below(swap, r, i) for i, r in enumerate(rots)], env.device)}


def pull_cube(env, swap: ActorSwap) -> dict:
    """PullCube-v1's success (the cube's x/y in the goal disc) reads no size; its reward reads
    ``cube_half_size`` for the hand's pulling pose: the candidate's, as :func:`push_cube`."""
    return push_cube(env, swap)


def stack_cube(env, swap: ActorSwap) -> dict:
    """StackCube-v1: cubeA is on cubeB when ``|zA - zB - 2 * cube_half_size[2]| <= 5 mm`` (and their x/y
    within ``|cube_half_size[:2]| + 5 mm``). The stock ``2 * cube_half_size[2]`` is cubeA's depth below its
    origin plus cubeB's top above its own (0.02 + 0.02). With a candidate cubeA, ``cube_half_size[2]`` is
    half of (the candidate's depth below its origin in its current orientation + cubeB's top above its
    origin in cubeB's orientation); cubeB is the stock cube (the same box as cubeA's stock geometry).
    The x/y bound (cubeB's top face) is kept. One sub-scene: the stock check indexes the vector itself."""
    import torch

    rot_a, rot_b = _rotations(env.cubeA)[0], _rotations(env.cubeB)[0]
    height = depth_below(swap, rot_a, 0) + top_above(swap.stock_hull(0), rot_b)
    half = env.cube_half_size if isinstance(env.cube_half_size, torch.Tensor) else torch.tensor([0.02] * 3)
    out = half.clone()
    out[2] = height / 2
    return {"cube_half_size": out}


def lift_peg_upright(env, swap: ActorSwap) -> dict:
    """LiftPegUpright-v1 succeeds when the peg stands upright with ``|z - peg_half_length| < 5 mm``: resting
    on its end. With a candidate, ``peg_half_length`` is the height of its origin when it rests in its
    current orientation (standing: the depth of the end that is down)."""
    rots = _rotations(env.peg)
    return {"peg_half_length": _scalar_or_tensor([depth_below(swap, r, i) for i, r in enumerate(rots)], env.device)}


def peg_insertion_side(env, swap: ActorSwap) -> dict:
    """PegInsertionSide-v1 judges the peg's *head point* ``peg.pose * peg_head_offsets`` (the +x end of the
    nominal box: ``(half length, 0, 0)``) inside the hole. With a candidate, the head point is the +x end of
    the candidate's parts on its axis (``(x_max, 0, 0)``), and ``peg_half_sizes`` (the size the state
    observation reports) is the candidate's half extents. The hole (``box_hole_radii``) is the box's, which
    is not swapped: it stays."""
    import torch
    from mani_skill.utils.structs.pose import Pose

    n = env.num_envs
    head = torch.zeros((n, 3), device=env.device)
    halves = torch.zeros((n, 3), device=env.device)
    for i in range(n):
        hull = swap.hull(i)
        head[i, 0] = float(hull[:, 0].max())
        halves[i] = torch.as_tensor(np.ptp(hull, axis=0) / 2, dtype=torch.float32)
    return {"peg_head_offsets": Pose.create_from_pq(p=head), "peg_half_sizes": halves}


def place_sphere(env, swap: ActorSwap) -> dict:
    """PlaceSphere-v1 judges the sphere on the bin by ``|z - z_bin - radius - block_half_size[0]| <= 5 mm``. With a
    candidate, ``radius`` is the height of its origin when it rests in its current orientation (as
    :func:`push_cube`); the bin is not swapped."""
    rots = _rotations(env.obj)
    return {"radius": _scalar_or_tensor([depth_below(swap, r, i) for i, r in enumerate(rots)], env.device)}


def poke_cube(env, swap: ActorSwap) -> dict:
    """PokeCube-v1's success reads no size of the peg, but its state observation and its peg-to-cube checks read
    the *head point* ``peg.pose * peg_head_offsets`` (the +x end of the nominal peg). With a candidate, the head
    point is the +x end of the candidate's parts on its axis, as :func:`peg_insertion_side`."""
    from mani_skill.utils.structs.pose import Pose

    heads = [[float(swap.hull(i)[:, 0].max()), 0.0, 0.0] for i in range(env.num_envs)]
    return {"peg_head_offsets": Pose.create_from_pq(p=heads)}
