"""Building blocks for the procedural objects: resampled profiles, revolutions, grid boxes, sweeps.

Everything here works in meters. Profiles are polylines in the ``(r, z)`` half-plane; they are
resampled so that triangles come out close to equilateral (the Jacobian-field deformer needs
non-degenerate, reasonably shaped faces), then revolved with manifold3d, which also performs the
Boolean unions of parts. :func:`to_trimesh` converts back and checks the result is valid.
"""

from __future__ import annotations

import manifold3d as m3
import numpy as np
import scipy.sparse as sp
import trimesh

CORNER_DEG = 30.0  # polyline vertices turning more than this are kept exactly (sharp corners)


def arc(center: tuple[float, float], radius: float, a0: float, a1: float, n: int = 48) -> np.ndarray:
    """Densely sampled circular arc in the ``(r, z)`` plane.

    Args:
        center: ``(r, z)`` center, meters.
        radius: meters.
        a0, a1: start and end angle (radians, measured from the +r axis, counter-clockwise).
        n: number of samples (resampling later sets the final density).

    Returns:
        ``(n, 2)`` points.
    """
    a = np.linspace(a0, a1, n)
    return np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], axis=1)


def _resample_piece(pts: np.ndarray, density) -> np.ndarray:
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    mid = 0.5 * (pts[1:] + pts[:-1])
    tau = np.concatenate([[0.0], np.cumsum(seg * density(mid))])
    n = max(1, int(np.ceil(tau[-1] - 1e-9)))
    t = np.linspace(0.0, tau[-1], n + 1)
    return np.stack([np.interp(t, tau, pts[:, k]) for k in range(2)], axis=1)


def resample(points: np.ndarray, spacing: float, segments: int, min_spacing: float,
             aspect: float = 1.5) -> np.ndarray:
    """Resample an open profile polyline for a revolution with ``segments`` around the axis.

    The local edge length follows ``aspect`` times the circumferential spacing ``2πr / segments``
    (quads of aspect ratio ``aspect``, triangles far from slivers), clipped to ``[min_spacing, spacing]``; sharp corners are kept exactly.

    Args:
        points: ``(K, 2)`` dense ``(r, z)`` polyline, meters, starting and ending on the axis.
        spacing: largest edge length, meters.
        segments: segments around the axis.
        min_spacing: smallest edge length, meters (bounds the face count of thin parts).
        aspect: profile edge length over circumferential edge length.

    Returns:
        ``(K', 2)`` resampled polyline.
    """
    pts = np.asarray(points, np.float64)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-12])
    pts = pts[keep]
    d = np.diff(pts, axis=0)
    # the z component of the 2-D cross product, written out: numpy 2.5 refuses np.cross on 2-D vectors
    turn = d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0]
    ang = np.degrees(np.arctan2(np.abs(turn), np.einsum("ij,ij->i", d[:-1], d[1:])))
    cuts = [0, *(np.flatnonzero(ang > CORNER_DEG) + 1).tolist(), len(pts) - 1]

    def density(p: np.ndarray) -> np.ndarray:
        return 1.0 / np.clip(aspect * 2 * np.pi * p[:, 0] / segments, min_spacing, spacing)

    out = [pts[:1]]
    for a, b in zip(cuts[:-1], cuts[1:], strict=False):
        out.append(_resample_piece(pts[a:b + 1], density)[1:])
    return np.concatenate(out)


def revolve(profile: np.ndarray, segments: int = 48, spacing: float | None = None,
            min_spacing: float = 0.001) -> m3.Manifold:
    """Solid of revolution about the z axis from an ``(r, z)`` profile.

    Args:
        profile: ``(K, 2)`` dense polyline from the axis (``r = 0``) around the solid and back to the
            axis, meters.
        segments: segments around the axis.
        spacing: largest edge length along the profile (default: the circumferential spacing at the
            largest radius, times 1.5).
        min_spacing: smallest edge length along the profile, meters.

    Returns:
        The solid as a ``manifold3d.Manifold``.
    """
    prof = np.asarray(profile, np.float64)
    prof[:, 0] = np.maximum(prof[:, 0], 0.0)
    if spacing is None:
        spacing = 1.5 * 2 * np.pi * prof[:, 0].max() / segments
    pts = resample(prof, spacing, segments, min_spacing)
    area = 0.5 * np.sum(pts[:-1, 0] * pts[1:, 1] - pts[1:, 0] * pts[:-1, 1])
    area += 0.5 * (pts[-1, 0] * pts[0, 1] - pts[0, 0] * pts[-1, 1])
    if area < 0:
        pts = pts[::-1]
    return m3.Manifold.revolve(m3.CrossSection([pts]), segments)


def rotate_z_to(solid: m3.Manifold, axis: str) -> m3.Manifold:
    """Rotate a solid built along +z so that its axis points along ``"x"`` or ``"y"``."""
    if axis == "x":
        return solid.rotate((0.0, 90.0, 0.0))
    if axis == "y":
        return solid.rotate((-90.0, 0.0, 0.0))
    raise ValueError(f"axis must be 'x' or 'y', got {axis!r}")


def grid_box(lo: tuple[float, float, float], hi: tuple[float, float, float], spacing: float) -> m3.Manifold:
    """Axis-aligned box whose faces are regular grids of right triangles.

    Args:
        lo, hi: ``(3,)`` corners, meters.
        spacing: target edge length, meters (each side gets ``ceil(extent / spacing)`` cells).

    Returns:
        The box as a ``manifold3d.Manifold``.
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    ticks = [np.linspace(lo[k], hi[k], max(1, int(np.ceil((hi[k] - lo[k]) / spacing - 1e-9))) + 1)
             for k in range(3)]
    verts, faces = [], []
    for axis in range(3):
        u, v = [k for k in range(3) if k != axis]
        for side, value in ((0, lo[axis]), (1, hi[axis])):
            gu, gv = np.meshgrid(ticks[u], ticks[v], indexing="ij")
            p = np.zeros((gu.size, 3))
            p[:, u], p[:, v], p[:, axis] = gu.ravel(), gv.ravel(), value
            nu, nv = gu.shape
            idx = np.arange(nu * nv).reshape(nu, nv) + sum(len(x) for x in verts)
            a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
            tri = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
            # (u, v, axis) is right-handed for axis 0 and 2 with this ordering, and left-handed for 1.
            flip = (side == 0) != (axis == 1)
            faces.append(tri[:, ::-1] if flip else tri)
            verts.append(p)
    mesh = trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=True)
    return to_manifold(mesh)


def sweep_tube(centerline, radius, rings: int, segments: int) -> trimesh.Trimesh:
    """Closed tube around a curve whose radius goes to zero at both ends (poles).

    Args:
        centerline: ``t -> (n, 3)`` points for ``t`` in ``[-π/2, π/2]`` (meters).
        radius: ``t -> (n,)`` radius, meters; positive inside, zero at ``±π/2``.
        rings: number of rings between the poles.
        segments: vertices per ring.

    Returns:
        A watertight tube mesh with outward normals.
    """
    t = np.linspace(-np.pi / 2, np.pi / 2, rings + 2)
    c = centerline(t)
    tangent = np.gradient(c, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    up = np.array([0.0, 0.0, 1.0])
    side = np.cross(tangent, up)
    side /= np.linalg.norm(side, axis=1, keepdims=True)
    normal = np.cross(side, tangent)
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    r = radius(t)[1:-1, None, None]
    ring = c[1:-1, None] + r * (np.cos(phi)[None, :, None] * side[1:-1, None]
                                 + np.sin(phi)[None, :, None] * normal[1:-1, None])
    verts = np.concatenate([ring.reshape(-1, 3), c[[0, -1]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    faces = []
    for k in range(rings - 1):
        a, b = k * segments + i, k * segments + j
        faces += [np.stack([a, b, b + segments], 1), np.stack([a, b + segments, a + segments], 1)]
    s0, s1 = rings * segments, rings * segments + 1
    last = (rings - 1) * segments
    faces += [np.stack([np.full(segments, s0), j, i], 1), np.stack([np.full(segments, s1), last + i, last + j], 1)]
    mesh = trimesh.Trimesh(verts, np.concatenate(faces), process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def sweep_profile(profile: np.ndarray, path, normal, segments: int, spacing: float | None = None,
                  min_spacing: float = 0.001) -> trimesh.Trimesh:
    """Solid of revolution about a bent axis: :func:`revolve` with its axis following a planar curve.

    Each profile point ``(r, s)`` becomes a ring of radius ``r`` around the path point at arc length
    ``s``, in the plane normal to the path there, so one mesh carries flat end pads, fillets and bends
    without Boolean seams.

    Args:
        profile: ``(K, 2)`` dense ``(r, s)`` polyline from the axis (``r = 0``) around the solid and
            back to the axis; ``s`` is arc length along the path, meters.
        path: ``s (n,) -> (points (n, 3), unit tangents (n, 3))``, meters; a curve in the plane normal
            to ``normal`` whose bend radius exceeds the profile's ``r`` wherever it bends.
        normal: ``(3,)`` unit normal of the path's plane.
        segments: vertices per ring.
        spacing, min_spacing: largest and smallest edge length along the profile, as in :func:`revolve`.

    Returns:
        A watertight mesh with outward normals.
    """
    prof = np.asarray(profile, np.float64)
    if spacing is None:
        spacing = 1.5 * 2 * np.pi * prof[:, 0].max() / segments
    pts = resample(prof, spacing, segments, min_spacing)
    c, t = path(pts[:, 1])
    n = np.broadcast_to(np.asarray(normal, np.float64), t.shape)
    u = np.cross(t, n)
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = c[1:-1, None] + pts[1:-1, 0, None, None] * (np.cos(phi)[None, :, None] * u[1:-1, None]
                                                      + np.sin(phi)[None, :, None] * n[1:-1, None])
    verts = np.concatenate([ring.reshape(-1, 3), c[[0, -1]]])
    rings = len(pts) - 2
    i = np.arange(segments)
    j = (i + 1) % segments
    faces = []
    for k in range(rings - 1):
        a, b = k * segments + i, k * segments + j
        faces += [np.stack([a, b, b + segments], 1), np.stack([a, b + segments, a + segments], 1)]
    s0, s1, last = rings * segments, rings * segments + 1, (rings - 1) * segments
    faces += [np.stack([np.full(segments, s0), j, i], 1), np.stack([np.full(segments, s1), last + i, last + j], 1)]
    mesh = trimesh.Trimesh(verts, np.concatenate(faces), process=True)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def to_manifold(mesh: trimesh.Trimesh) -> m3.Manifold:
    """trimesh -> manifold3d (float32 vertices, as manifold3d stores them)."""
    return m3.Manifold(m3.Mesh(vert_properties=np.asarray(mesh.vertices, np.float32),
                               tri_verts=np.asarray(mesh.faces, np.uint32)))


def to_trimesh(solid: m3.Manifold | trimesh.Trimesh) -> trimesh.Trimesh:
    """manifold3d -> trimesh in float64, checked to be one valid solid.

    Raises:
        RuntimeError: the construction produced an invalid or multi-part solid (a bug in a builder).
    """
    if isinstance(solid, trimesh.Trimesh):
        return solid
    if solid.status() != m3.Error.NoError:
        raise RuntimeError(f"manifold3d construction failed: {solid.status()}")
    raw = solid.to_mesh()
    mesh = trimesh.Trimesh(np.asarray(raw.vert_properties)[:, :3].astype(np.float64),
                           np.asarray(raw.tri_verts).astype(np.int64), process=False)
    if not mesh.is_watertight or len(mesh.split(only_watertight=False)) != 1:
        raise RuntimeError("object construction produced a non-watertight or multi-part mesh")
    return mesh


def min_face_angles(mesh: trimesh.Trimesh) -> np.ndarray:
    """``(F,)`` smallest interior angle of each face, degrees (sliver check)."""
    return np.degrees(np.asarray(mesh.face_angles).min(axis=1))


def _angles(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    p = v[f]
    out = []
    for k in range(3):
        a, b = p[:, (k + 1) % 3] - p[:, k], p[:, (k + 2) % 3] - p[:, k]
        cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1) + 1e-300)
        out.append(np.arccos(np.clip(cos, -1, 1)))
    return np.degrees(np.stack(out, 1))


def _flip_round(mesh: trimesh.Trimesh, min_angle: float, max_dihedral: float) -> tuple[trimesh.Trimesh, int]:
    """Flip edges next to sliver faces where both new faces are better shaped (Delaunay-like)."""
    v, f = mesh.vertices, mesh.faces.copy()
    worst = _angles(v, f).min(1)
    pairs, edges = mesh.face_adjacency, mesh.face_adjacency_edges
    opp = mesh.face_adjacency_unshared
    cand = (np.minimum(worst[pairs[:, 0]], worst[pairs[:, 1]]) < min_angle)
    cand &= np.degrees(mesh.face_adjacency_angles) < max_dihedral
    existing = {tuple(e) for e in np.sort(mesh.edges_unique, axis=1).tolist()}
    used, n = np.zeros(len(f), bool), 0
    for i in np.flatnonzero(cand)[np.argsort(np.minimum(worst[pairs[cand, 0]], worst[pairs[cand, 1]]))]:
        f1, f2 = pairs[i]
        c, d = opp[i]
        if used[f1] or used[f2] or (min(c, d), max(c, d)) in existing:
            continue
        u, w = edges[i]
        row = list(f[f1])
        if row[(row.index(u) + 1) % 3] != w:  # orient so f1 = (u, w, c)
            u, w = w, u
        new = np.array([[c, u, d], [d, w, c]])
        if _angles(v, new).min() <= min(worst[f1], worst[f2]):
            continue
        n_old = np.cross(v[w] - v[u], v[c] - v[u])
        n_new = np.cross(v[new[:, 1]] - v[new[:, 0]], v[new[:, 2]] - v[new[:, 0]])
        if np.any(n_new @ n_old <= 0):
            continue
        f[f1], f[f2] = new
        used[[f1, f2]] = True
        existing.add((min(c, d), max(c, d)))
        n += 1
    return trimesh.Trimesh(v, f, process=False), n


def _collapse_round(mesh: trimesh.Trimesh, ratio: float, max_len: float) -> tuple[trimesh.Trimesh, int]:
    """Collapse edges shorter than ``max_len`` and than ``ratio`` times the other edges of their face."""
    v, f = mesh.vertices.copy(), mesh.faces
    e = np.linalg.norm(v[f[:, [1, 2, 0]]] - v[f], axis=2)  # edge k joins corners k and k+1
    order = np.sort(e, axis=1)
    needle = (order[:, 0] < ratio * order[:, 1]) & (order[:, 0] < max_len)
    eu = mesh.edges_unique
    adj = sp.csr_matrix((np.ones(2 * len(eu)), (eu.ravel(), eu[:, ::-1].ravel())), shape=(len(v),) * 2)

    def ring_of(i: int) -> set:
        return set(adj.indices[adj.indptr[i]:adj.indptr[i + 1]].tolist())
    target = np.arange(len(v))
    touched = np.zeros(len(v), bool)
    n = 0
    for fi in np.flatnonzero(needle):
        k = int(np.argmin(e[fi]))
        a, b = int(f[fi, k]), int(f[fi, (k + 1) % 3])
        na, nb = ring_of(a), ring_of(b)
        ring = na | nb | {a, b}
        if touched[list(ring)].any() or len(na & nb) != 2:
            continue  # the link condition keeps the mesh manifold
        v[a] = v[b] = 0.5 * (v[a] + v[b])
        target[b] = a
        touched[list(ring)] = True
        n += 1
    faces = target[f]
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    out = trimesh.Trimesh(v, faces[keep], process=False)
    out.remove_unreferenced_vertices()
    return out, n


def clean_slivers(mesh: trimesh.Trimesh, min_angle: float = 5.0, max_dihedral: float = 10.0,
                  rounds: int = 6, max_len: float = 3e-4) -> trimesh.Trimesh:
    """Remove sliver triangles left by Boolean seams: collapse needles, flip caps.

    Flips only act across nearly flat edges (dihedral below ``max_dihedral`` degrees) and collapses
    only move vertices by half an edge shorter than ``max_len``, so the surface moves by at most
    ``max_len / 2`` (0.15 mm by default). Boolean seams across sharp creases can keep a few slivers.

    Args:
        mesh: watertight mesh, meters.
        min_angle: faces with a smaller interior angle (degrees) are treated as slivers.
        max_dihedral: largest dihedral angle (degrees) across which an edge may be flipped.
        rounds: at most this many collapse + flip rounds.
        max_len: longest edge that may be collapsed, meters.

    Returns:
        A new mesh; if a round would break watertightness it is dropped and cleaning stops.
    """
    for _ in range(rounds):
        if min_face_angles(mesh).min() >= min_angle:
            break
        collapsed, n_c = _collapse_round(mesh, ratio=0.2, max_len=max_len)
        if n_c and collapsed.is_watertight and collapsed.is_winding_consistent:
            mesh = collapsed
        flipped, n_f = _flip_round(mesh, min_angle, max_dihedral)
        if n_f and flipped.is_watertight and flipped.is_winding_consistent:
            mesh = flipped
        if not n_c and not n_f:
            break
    return mesh
