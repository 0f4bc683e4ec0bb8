"""A socket matched to a plug: convex wall pieces around the plug head's cross-section, with a chamfer.

The hole is the XY convex hull of the nominal plug's head (the vertices below ``head_length``),
grown by ``clearance`` on every side; the walls are convex prisms between the hole's outline and a
round outer wall, so the socket collides as convex parts (robust in PhysX, also on a GPU) and needs no
decomposition. The entrance has a 45 degree chamfer of ``chamfer`` meters, as real sockets do.

Frame: the socket's top face is ``z = 0``, the hole's floor ``z = -depth``; the hole is centered at
the origin (the head's XY hull center).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from grt.tasks.base import TaskInputError


class PlugFitError(TaskInputError):
    """The plug cannot be inserted into a socket built for it (too wide, no head)."""


@dataclass
class SocketGeometry:
    """Convex parts and a visual mesh of a socket, in the socket frame (meters).

    Attributes:
        parts: convex pieces, each ``(K, 3)``.
        mesh: visual mesh (union of the pieces' hulls).
        hole: ``(P, 2)`` outline of the hole (counter-clockwise), meters.
        center: ``(2,)`` XY of the head's hull center in the plug frame (the plug's insertion axis).
        depth: hole depth (m); ``outer_radius``: radius of the socket's outer wall (m).
    """

    parts: list[np.ndarray]
    mesh: trimesh.Trimesh
    hole: np.ndarray
    center: np.ndarray
    depth: float
    outer_radius: float


def grip_half_width(plug: trimesh.Trimesh, grip_height: float, band: float = 0.008) -> float:
    """Largest |y| (m) of the plug within ``band`` of ``grip_height``: where the fingers close on it.

    Raises:
        PlugFitError: no surface there (the fingers would close on nothing).
    """
    v = np.asarray(plug.vertices)
    near = v[np.abs(v[:, 2] - grip_height) < band]
    if len(near) == 0:
        raise PlugFitError(f"the plug has no surface within {band * 1000:.0f} mm of grip_height={grip_height} m: "
                           "set task.session.grip_height to where the fingers should hold it (m above the tip)")
    return float(np.abs(near[:, 1]).max())


def head_outline(plug: trimesh.Trimesh, head_length: float) -> np.ndarray:
    """``(P, 2)`` XY convex hull (counter-clockwise) of the plug's vertices with ``z <= head_length``.

    Raises:
        PlugFitError: fewer than 3 head vertices, or a degenerate (flat) head.
    """
    verts = np.asarray(plug.vertices)
    head = verts[verts[:, 2] <= head_length + 1e-9, :2]
    if len(head) < 3:
        raise PlugFitError(f"the plug has {len(head)} vertices below head_length={head_length} m: no head to "
                           "insert; set task.session.head_length to the connector's length (m)")
    try:
        hull = ConvexHull(head)
    except Exception as err:
        raise PlugFitError(f"the plug's head cross-section is degenerate ({err}); is the mesh in meters, "
                           "standing on its connector (z up)?") from err
    return head[hull.vertices]


def grow_polygon(poly: np.ndarray, offset: float) -> np.ndarray:
    """A convex counter-clockwise polygon ``(P, 2)`` with every edge moved outward by ``offset`` (mitred)."""
    edges = np.roll(poly, -1, axis=0) - poly
    normals = np.stack([edges[:, 1], -edges[:, 0]], 1) / np.linalg.norm(edges, axis=1, keepdims=True)
    prev = np.roll(normals, 1, axis=0)  # normal of the edge ending at each vertex
    return poly + offset * (normals + prev) / (1.0 + np.einsum("ij,ij->i", normals, prev))[:, None]


def build_socket(plug: trimesh.Trimesh, head_length: float, clearance: float = 0.0004,
                 chamfer: float = 0.0015, depth_margin: float = 0.001, wall: float = 0.012,
                 base_height: float = 0.07) -> SocketGeometry:
    """A socket for ``plug`` (the nominal plug, meters, connector down, tip at z = 0).

    Args:
        plug: the plug mesh in its own frame.
        head_length: length (m) of the connector head (what goes into the hole).
        clearance: gap (m) between head and hole on every side (0.4 mm: 0.8 mm in total).
        chamfer: width (m) of the 45 degree entrance chamfer.
        depth_margin: hole depth beyond the head length (m): the plug bottoms out on its shoulder.
        wall: thinnest wall (m) between the hole and the outer cylinder.
        base_height: height (m) of the socket body below its top face (it reaches into the table).

    Raises:
        PlugFitError: the head is missing or degenerate.
    """
    outline = head_outline(plug, head_length)
    center = outline.mean(axis=0)
    hole = grow_polygon(outline - center, clearance)
    depth = head_length + depth_margin
    radii = np.linalg.norm(hole, axis=1)
    outer = float(radii.max() + chamfer + wall)
    parts = []
    for i in range(len(hole)):
        a, b = hole[i], hole[(i + 1) % len(hole)]
        ua, ub = a / np.linalg.norm(a), b / np.linalg.norm(b)
        piece = []
        for p, u in ((a, ua), (b, ub)):
            piece += [[*p, -base_height], [*p, -chamfer], [*(p + chamfer * u), 0.0], [*(outer * u), 0.0],
                      [*(outer * u), -base_height]]
        parts.append(np.asarray(piece, np.float64))
    # The floor of the hole: a prism under the outline, down to the socket's base.
    floor = np.concatenate([np.c_[hole, np.full(len(hole), -depth)], np.c_[hole, np.full(len(hole), -base_height)]])
    parts.append(floor)
    hulls = [trimesh.convex.convex_hull(p) for p in parts]
    mesh = trimesh.util.concatenate(hulls)
    return SocketGeometry(parts=parts, mesh=mesh, hole=hole, center=center, depth=depth, outer_radius=outer)
