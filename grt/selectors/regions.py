"""Regions of an object's surface given in config: boxes, spheres, or named built-in regions.

A region spec is one of (coordinates in the mesh's frame, meters for GRT meshes):

* ``{"box": [[x0, y0, z0], [x1, y1, z1]]}``: an axis-aligned box (corners in any order);
* ``{"sphere": {"center": [x, y, z], "radius": r}}``: a ball;
* ``"OBJECT:REGION"`` (e.g. ``"mug:handle"``): a named region of a built-in object,
  ``grt.objects.object_regions(OBJECT)[REGION]`` (an axis-aligned box ``(2, 3)`` in meters);
* ``{"plug": "head" | "grip", "object": OBJECT, "head_length": h}``: a plug's connector (``z <= h - 0.5 mm``)
  or the body the fingers hold (``z >= h + 0.5 mm``), tip at z = 0 (the insertion task's manual regions): a
  built-in plug's named region, a user's plug's from ``head_length`` (``task.session.head_length``);
* ``{"handle": "grip" | "left_foot" | "right_foot", "object": OBJECT, "grasp_point": [x, y, z]}``: a drawer
  handle's grip (``z >= 0.75 z_g``) or its feet (``z <= 0.25 z_g``, ``x < 0`` or ``x > 0``), z = 0 the
  mounting plane: a built-in handle's named region, a user's handle's from ``grasp_point``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from grt.objects import list_objects, object_regions
from grt.selectors.base import SelectorError

RegionSpec = Mapping | str


def named_region_box(spec: str) -> np.ndarray:
    """The ``(2, 3)`` box (meters) of a named built-in region ``"OBJECT:REGION"``."""
    obj, sep, name = spec.partition(":")
    if not sep or not obj or not name:
        raise SelectorError(f"region {spec!r}: a named region is written 'OBJECT:REGION', e.g. 'mug:handle'")
    regions = object_regions(obj)
    if name not in regions:
        raise SelectorError(f"object {obj!r} has no region {name!r}; its regions are: {', '.join(sorted(regions))}")
    region = regions[name]
    return np.asarray(getattr(region, "box", region), dtype=np.float64).reshape(2, 3)


def region_mask(points: np.ndarray, spec: RegionSpec) -> np.ndarray:
    """Which points lie in a region (boundary included).

    Args:
        points: ``(V, 3)`` positions (meters).
        spec: a region spec (module docstring).

    Returns:
        ``(V,)`` bool mask.
    """
    points = np.asarray(points, dtype=np.float64)
    if isinstance(spec, str):
        box = named_region_box(spec)
    elif isinstance(spec, Mapping) and ("plug" in spec or "handle" in spec):
        return _part_mask(points, spec)
    elif isinstance(spec, Mapping) and "box" in spec:
        box = np.asarray(spec["box"], dtype=np.float64).reshape(2, 3)
    elif isinstance(spec, Mapping) and "sphere" in spec:
        ball = spec["sphere"]
        center = np.asarray(ball["center"], dtype=np.float64).reshape(3)
        return np.linalg.norm(points - center, axis=1) <= float(ball["radius"])
    else:
        raise SelectorError(f"unknown region spec {spec!r}: use {{'box': [[x0,y0,z0],[x1,y1,z1]]}}, "
                         "{'sphere': {'center': [x,y,z], 'radius': r}} or 'OBJECT:REGION'")
    lo, hi = box.min(0), box.max(0)
    return np.all((points >= lo) & (points <= hi), axis=1)


def region_vertices(points: np.ndarray, specs: Iterable[RegionSpec]) -> np.ndarray:
    """Sorted unique indices of the points inside any of the regions, ``(K,)`` int."""
    mask = np.zeros(len(points), dtype=bool)
    for spec in specs:
        mask |= region_mask(points, spec)
    return np.flatnonzero(mask).astype(np.int64)


def _part_mask(points: np.ndarray, spec: Mapping) -> np.ndarray:
    """A plug's or a drawer handle's part (module docstring): named on a built-in object, else derived."""
    kind = "plug" if "plug" in spec else "handle"
    name, obj = str(spec[kind]), str(spec.get("object", ""))
    if obj in list_objects() and name in object_regions(obj):
        return region_mask(points, f"{obj}:{name}")
    z, x = points[:, 2], points[:, 0]
    if kind == "plug":
        head = spec.get("head_length")
        if head is None:
            raise SelectorError(f"manual regions of the plug {obj!r}: its head and grip are found from its connector "
                             "length; set task.session.head_length (m from the tip at z = 0)")
        if name not in ("head", "grip"):
            raise SelectorError(f"a plug's regions are head and grip, not {name!r}")
        return z <= float(head) - 0.0005 if name == "head" else z >= float(head) + 0.0005
    point = spec.get("grasp_point")
    if point is None:
        raise SelectorError(f"manual regions of the handle {obj!r}: its grip and feet are found from its grasp point; "
                         "set task.session.grasp_point=[x,y,z] (m, z = 0 the mounting plane)")
    height = float(list(point)[2])
    masks = {"grip": z >= 0.75 * height, "left_foot": (z <= 0.25 * height) & (x < 0),
             "right_foot": (z <= 0.25 * height) & (x > 0)}
    if name not in masks:
        raise SelectorError(f"a drawer handle's regions are {', '.join(masks)}, not {name!r}")
    return masks[name]
