"""Built-in household objects, generated procedurally: meters, z up, resting on z = 0.

Every object is a watertight, single-component, manifold, outward-oriented triangle mesh at
real-world size, centered in x/y with its lowest point on ``z = 0`` (the pose it takes on a table),
built in well under a second and cached (Boolean seams are cleaned of sliver triangles). Named regions (e.g. ``mug: handle``, ``plug: head``) are
axis-aligned boxes in the same frame, used to pick handles and anchors.

Example::

    from grt.objects import get_object, object_regions
    mug = get_object("mug")                     # trimesh.Trimesh, meters
    box = object_regions("mug")["handle"]       # (2, 3): min and max corner, meters
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

from grt.errors import UserError
from grt.objects.catalog import BUILDERS, DESCRIPTIONS, DRAWER, INSERTION
from grt.objects.shapes import clean_slivers, to_trimesh

__all__ = ["UnknownObjectError", "get_object", "list_objects", "object_info", "object_regions", "object_task"]


class UnknownObjectError(UserError):
    """An object name that is neither built in nor (where a path is accepted) an existing file."""

    def __init__(self, name: str):
        self.name = name
        super().__init__(f"unknown object {name!r}. Built-in objects: {', '.join(list_objects())}. "
                         "A path to a mesh file (OBJ, STL, PLY, GLB, OFF; meters) also works.")


def list_objects() -> list[str]:
    """Names of the built-in objects, sorted."""
    return sorted(BUILDERS)


@functools.cache
def _build(name: str) -> tuple[trimesh.Trimesh, dict[str, np.ndarray]]:
    solid, regions = BUILDERS[name]()
    mesh = clean_slivers(to_trimesh(solid))
    if mesh.volume < 0:
        mesh.invert()
    lo, hi = mesh.bounds
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    mesh.apply_translation(shift)
    mesh.metadata["grt_object"] = name
    # 1 mm of padding: vertices on a region's boundary (stored as float32 by manifold3d) stay inside.
    pad = np.array([[-1e-3], [1e-3]])
    return mesh, {k: np.asarray(v, np.float64) + shift + pad for k, v in regions.items()}


def _check(name: str) -> None:
    if name not in BUILDERS:
        raise UnknownObjectError(name)


def get_object(name: str) -> trimesh.Trimesh:
    """The built-in object ``name`` as a new mesh (meters, z up, on z = 0, centered in x/y).

    Raises:
        UnknownObjectError: ``name`` is not built in (the message lists the known names).
    """
    _check(name)
    return _build(name)[0].copy()


def object_regions(name: str) -> dict[str, np.ndarray]:
    """Named parts of a built-in object: ``{part: (2, 3) array [min corner, max corner]}``, meters.

    Raises:
        UnknownObjectError: ``name`` is not built in.
    """
    _check(name)
    return {k: v.copy() for k, v in _build(name)[1].items()}


def object_task(name: str) -> str:
    """The task a built-in object is made for: ``insertion`` (a plug standing on its connector, with the
    head length and grip height the socket is built from), ``drawer`` (a handle with its grasp point) or
    ``grasp`` (a household object resting on the table; ``plug`` lies on its side and is one of these).

    Raises:
        UnknownObjectError: ``name`` is not built in.
    """
    _check(name)
    return "insertion" if name in INSERTION else "drawer" if name in DRAWER else "grasp"


def object_info(name: str) -> dict:
    """Facts about a built-in object: ``description`` (used in prompts), ``regions`` (names), ``task`` (the
    task it is made for, :func:`object_task`), for
    plugs ``insertion`` (``head_length``, ``grip_height`` in meters), and for drawer handles
    ``drawer`` (``grasp``: ``[x, y, z]`` grasp point on the grip's axis, ``grip_radius``; meters, in
    the frame :func:`get_object` returns).

    Raises:
        UnknownObjectError: ``name`` is not built in.
    """
    _check(name)
    info = {"description": DESCRIPTIONS[name], "regions": sorted(_build(name)[1]), "task": object_task(name)}
    if name in INSERTION:
        info["insertion"] = dict(INSERTION[name])
    if name in DRAWER:
        info["drawer"] = {k: list(v) if isinstance(v, list) else v for k, v in DRAWER[name].items()}
    return info
