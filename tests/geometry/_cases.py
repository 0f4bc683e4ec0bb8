"""Procedural input cases of the mesh pipeline (issue 12), in meters: built in the tests, never committed."""

from __future__ import annotations

import numpy as np
import trimesh


def open_can(radius: float = 0.033, height: float = 0.12, gap: float = 0.003) -> trimesh.Trimesh:
    """A can made of three separate sheets: an open side wall, and a lid and a bottom (thin closed discs)
    each ``gap`` away from the wall's rims."""
    wall = trimesh.creation.cylinder(radius, height, sections=64)
    wall.update_faces(np.abs(wall.face_normals[:, 2]) < 0.5)  # drop the caps: an open tube
    wall.remove_unreferenced_vertices()
    lid = trimesh.creation.cylinder(radius * 0.97, 0.004, sections=64)
    lid.apply_translation([0, 0, height / 2 + gap])
    bottom = lid.copy()
    bottom.apply_translation([0, 0, -height - 2 * gap])
    can = trimesh.util.concatenate([wall, lid, bottom])
    can.apply_translation([0, 0, height / 2 + gap + 0.004])
    return can


def two_spheres(radius: float = 0.03, distance: float = 0.1) -> trimesh.Trimesh:
    """Two disjoint spheres in one mesh."""
    a = trimesh.creation.icosphere(3, radius=radius)
    b = a.copy()
    b.apply_translation([distance, 0, 0])
    return trimesh.util.concatenate([a, b])


def overlapping_spheres(radius: float = 0.03, distance: float = 0.04) -> trimesh.Trimesh:
    """Two overlapping spheres in one mesh (one solid once united)."""
    return two_spheres(radius, distance)


def cubes_sharing_an_edge(size: float = 0.05) -> trimesh.Trimesh:
    """Two cubes that touch only along one edge (its vertices shared): no common volume."""
    a = trimesh.creation.box([size] * 3)
    b = a.copy()
    b.apply_translation([size, size, 0])
    both = trimesh.util.concatenate([a, b])
    both.merge_vertices()
    return both


def coarse_cad(seed: int = 0) -> trimesh.Trimesh:
    """A low-poly CAD-like part (~90 vertices, long thin triangles): a box with a chamfered slot, as a CAD
    exporter triangulates it (fans across whole faces)."""
    body = trimesh.creation.box([0.12, 0.06, 0.04])
    slot = trimesh.creation.cylinder(0.012, 0.08, sections=64)
    slot.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    slot.apply_translation([0.03, 0, 0.02])
    return body.difference(slot)


def very_fine_sphere(radius: float = 0.05) -> trimesh.Trimesh:
    """An icosphere with 327,680 faces (the issue's "330k-face sphere")."""
    return trimesh.creation.icosphere(7, radius=radius)


def inside_out(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` with every face's winding reversed (normals pointing inwards)."""
    out = mesh.copy()
    out.invert()
    return out
