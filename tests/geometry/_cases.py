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


def with_seam_caps(mesh: trimesh.Trimesh, caps: int, seed: int = 0) -> trimesh.Trimesh:
    """``mesh`` (closed) with ``caps`` T-junctions along its crease edges, each closed by a zero-area face, as
    CAD exporters leave them along seams: a face beside the edge ``ab`` is split at the edge's midpoint
    ``c``, the face on the other side is not, and the flat face ``(a, b, c)`` closes the gap. Watertight."""
    m = mesh.copy()
    m.merge_vertices()
    v, f = list(np.asarray(m.vertices)), [list(x) for x in np.asarray(m.faces)]
    pairs = m.face_adjacency[m.face_adjacency_angles > np.radians(20)]
    used: set[int] = set()
    for i, j in pairs[np.random.default_rng(seed).permutation(len(pairs))]:
        if len(used) == 2 * caps:
            break
        if i in used or j in used:
            continue
        used |= {int(i), int(j)}
        t = next(t for t in range(3) if f[i][t] in f[j] and f[i][(t + 1) % 3] in f[j])
        a, b, x = f[i][t], f[i][(t + 1) % 3], f[i][(t + 2) % 3]
        c = len(v)
        v.append((v[a] + v[b]) / 2)
        f[i] = [a, c, x]
        f += [[c, b, x], [a, b, c]]
    return trimesh.Trimesh(np.array(v), np.array(f), process=False)


def carton(size=(0.07, 0.07, 0.2), caps: int = 7) -> trimesh.Trimesh:
    """A closed carton (a box, its sides split once) whose closure uses ``caps`` zero-area faces."""
    box = trimesh.creation.box(size)
    box.apply_translation([0, 0, size[2] / 2])
    v, f = trimesh.remesh.subdivide(box.vertices, box.faces)
    fine = trimesh.Trimesh(v, f)
    return with_seam_caps(fine, caps)


def uv_sphere(radius: float = 0.05, n_lon: int = 600, n_lat: int = 450) -> trimesh.Trimesh:
    """A closed UV sphere as Blender or Open3D make it (one vertex per pole, a triangle fan around it): 539k
    faces by default. One aggressive quadric decimation of it to ~12k faces keeps 0.54 of its volume."""
    th = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]]) * radius
    k = np.arange(n_lon)

    def at(r, kk):
        return 1 + r * n_lon + kk % n_lon

    f = [np.stack([np.zeros(n_lon, int), at(0, k), at(0, k + 1)], 1)]
    for r in range(n_lat - 2):
        f += [np.stack([at(r, k), at(r + 1, k), at(r + 1, k + 1)], 1), np.stack([at(r, k), at(r + 1, k + 1), at(r, k + 1)], 1)]
    f.append(np.stack([np.full(n_lon, len(v) - 1), at(n_lat - 2, k + 1), at(n_lat - 2, k)], 1))
    sphere = trimesh.Trimesh(v, np.concatenate(f), process=False)
    if sphere.volume < 0:
        sphere.invert()
    return sphere
