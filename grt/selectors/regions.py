"""Regions of an object's surface given in config: boxes, spheres, or named built-in regions.

A region spec is one of (coordinates in the mesh's frame, meters for GRT meshes):

* ``{"box": [[x0, y0, z0], [x1, y1, z1]]}``: an axis-aligned box (corners in any order);
* ``{"sphere": {"center": [x, y, z], "radius": r}}``: a ball;
* ``"OBJECT:REGION"`` (e.g. ``"mug:handle"``): a named region of a built-in object,
  ``grt.objects.object_regions(OBJECT)[REGION]`` (an axis-aligned box ``(2, 3)`` in meters).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np

from grt.objects import object_regions
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
