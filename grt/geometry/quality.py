"""Is a deformed mesh a plausible, printable object? Spikes, self-intersections, inverted faces.

* :func:`spike_ratios` — issue 12's spike measure: each handle's displacement over the mean
  displacement of the other vertices within 5 % of the bounding-box diagonal of it. A smooth bump at
  least that wide gives <= 1.3; a point handle's tent gives 2-3.
* :func:`self_intersections` — pairs of non-adjacent triangles that cross (exact segment/triangle
  tests after a uniform-grid broad phase, numpy only). A deformation keeps the faces, so a candidate
  stays watertight and consistently wound; what it can lose is embeddedness: a wall pushed through
  another, or a fold.
* :func:`inverted_faces` — faces whose normal turned by more than 90° against the nominal mesh
  (a fold that no pair test sees, since the folded faces share vertices).
* :func:`candidate_validity` — the three together, as stored in each journal record.
"""

from __future__ import annotations

import numpy as np
import trimesh

SPIKE_RADIUS = 0.05  # of the bounding-box diagonal (issue 12)


def spike_ratios(nominal: np.ndarray, deformed: np.ndarray, handles: np.ndarray,
                 radius: float = SPIKE_RADIUS) -> np.ndarray:
    """Displacement of each handle over the mean displacement of its neighbours.

    Args:
        nominal: ``(V, 3)`` rest vertices.
        deformed: ``(V, 3)`` deformed vertices (same order, same units).
        handles: ``(H,)`` handle vertex indices.
        radius: neighbourhood radius as a fraction of the nominal bounding-box diagonal (Euclidean).

    Returns:
        ``(H,)`` ratios; NaN for a handle with no neighbour or with neighbours that did not move.
    """
    nominal, deformed = np.asarray(nominal, np.float64), np.asarray(deformed, np.float64)
    disp = np.linalg.norm(deformed - nominal, axis=1)
    r = radius * float(np.linalg.norm(np.ptp(nominal, axis=0)))
    out = np.full(len(handles), np.nan)
    for k, h in enumerate(np.asarray(handles, np.int64)):
        near = np.linalg.norm(nominal - nominal[h], axis=1) <= r
        near[h] = False
        if near.any():
            mean = disp[near].mean()
            if mean > 0:
                out[k] = disp[h] / mean
    return out


def _candidate_pairs(tris: np.ndarray) -> np.ndarray:
    """``(P, 2)`` face pairs (a < b) whose bounding boxes overlap, from a uniform grid."""
    lo, hi = tris.min(1), tris.max(1)
    cell = 2.0 * float(np.median((hi - lo).max(1))) or 1.0
    origin = lo.min(0)
    c0 = np.floor((lo - origin) / cell).astype(np.int64)
    c1 = np.floor((hi - origin) / cell).astype(np.int64)
    span = c1 - c0 + 1
    count = span.prod(1)
    face = np.repeat(np.arange(len(tris)), count)
    # k-th cell of a face's block, unravelled over its (sx, sy, sz) span
    k = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    sy, sz = span[face, 1], span[face, 2]
    cells = c0[face] + np.stack([k // (sy * sz), (k // sz) % sy, k % sz], axis=1)
    dims = cells.max(0) + 1
    key = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    order = np.argsort(key, kind="stable")
    key, face = key[order], face[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    sizes = np.diff(np.r_[starts, len(key)])
    # every pair inside a cell: entry e pairs with the entries after it in its cell
    group_end = np.repeat(starts + sizes, sizes)
    after = group_end - np.arange(len(key)) - 1
    first = np.repeat(np.arange(len(key)), after)
    second = first + 1 + (np.arange(after.sum()) - np.repeat(np.cumsum(after) - after, after))
    a, b = face[first], face[second]
    pairs = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    overlap = np.all((lo[pairs[:, 0]] <= hi[pairs[:, 1]]) & (lo[pairs[:, 1]] <= hi[pairs[:, 0]]), axis=1)
    return pairs[overlap]


def _segments_cross(p: np.ndarray, q: np.ndarray, tri: np.ndarray, eps: float) -> np.ndarray:
    """Does segment ``p->q`` (``(N, 3)``) cross triangle ``tri`` (``(N, 3, 3)``)? Möller-Trumbore."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    d = q - p
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    ok = np.abs(det) > eps
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p - tri[:, 0]
    u = inv * np.einsum("ij,ij->i", s, h)
    qv = np.cross(s, e1)
    v = inv * np.einsum("ij,ij->i", d, qv)
    t = inv * np.einsum("ij,ij->i", e2, qv)
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def self_intersections(vertices: np.ndarray, faces: np.ndarray) -> int:
    """Number of pairs of triangles that share no vertex and cross each other.

    Args:
        vertices: ``(V, 3)`` positions.
        faces: ``(F, 3)`` triangles.

    Returns:
        The count (0 for an embedded surface). Touching in exactly one point may or may not count;
        coplanar overlaps are not counted (they do not arise from a smooth deformation).
    """
    return len(crossing_pairs(vertices, faces))


def crossing_pairs(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``(K, 2)`` face index pairs ``(a < b)`` that share no vertex and cross (see :func:`self_intersections`)."""
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    tris = vertices[faces]
    pairs = _candidate_pairs(tris)
    fa, fb = faces[pairs[:, 0]], faces[pairs[:, 1]]
    shared = (fa[:, :, None] == fb[:, None, :]).any((1, 2))
    pairs = pairs[~shared]
    if len(pairs) == 0:
        return np.empty((0, 2), np.int64)
    ta, tb = tris[pairs[:, 0]], tris[pairs[:, 1]]
    eps = 1e-12 * float(np.ptp(vertices, axis=0).max()) ** 2
    hit = np.zeros(len(pairs), bool)
    for x, y in ((ta, tb), (tb, ta)):
        for i in range(3):
            hit |= _segments_cross(x[:, i], x[:, (i + 1) % 3], y, eps)
    return np.sort(pairs[hit], axis=1)


def nominal_crossings(nominal: trimesh.Trimesh) -> np.ndarray:
    """The nominal mesh's own crossing pairs (a real input may already cross itself), computed once."""
    if "grt_crossing_pairs" not in nominal.metadata:
        nominal.metadata["grt_crossing_pairs"] = crossing_pairs(nominal.vertices, nominal.faces)
    return nominal.metadata["grt_crossing_pairs"]


def inverted_faces(nominal: trimesh.Trimesh, vertices: np.ndarray) -> int:
    """Faces whose normal points more than 90° away from the same face's nominal normal."""
    v = np.asarray(vertices, np.float64)[np.asarray(nominal.faces)]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return int((np.einsum("ij,ij->i", n, np.asarray(nominal.face_normals)) < 0).sum())


def candidate_validity(nominal: trimesh.Trimesh, mesh: trimesh.Trimesh,
                       max_volume_change: float | None = None) -> dict:
    """What every journal record stores about a candidate's plausibility.

    Args:
        nominal: the nominal mesh; mesh: the candidate (same vertex order and faces).
        max_volume_change: the largest relative change of the enclosed volume a plausible candidate may
            have (``deformer.max_volume_change``; ``None``: not checked). A bump that takes a quarter of a
            small fruit's volume is not the same object.

    Returns:
        ``{"self_intersections": int, "inverted_faces": int, "watertight": bool,
        "winding_consistent": bool, "valid": bool}``, and with ``max_volume_change`` ``"volume_change"``;
        ``valid`` needs all of them to be good.
        ``self_intersections`` counts the crossing face pairs the deformation *added*: a crossing the
        nominal mesh already has (reported when it was loaded) is the input's, not the candidate's.
    """
    own = {tuple(p) for p in nominal_crossings(nominal).tolist()}
    si = sum(tuple(p) not in own for p in crossing_pairs(mesh.vertices, mesh.faces).tolist())
    inv = inverted_faces(nominal, mesh.vertices)
    watertight = bool(mesh.is_watertight)
    winding = bool(mesh.is_winding_consistent)
    out = {"self_intersections": si, "inverted_faces": inv, "watertight": watertight,
           "winding_consistent": winding, "valid": bool(si == 0 and inv == 0 and watertight and winding)}
    if max_volume_change is not None:
        v0 = abs(float(nominal.volume))
        change = abs(float(mesh.volume)) / v0 - 1.0 if v0 > 0 else 0.0
        out["volume_change"] = round(change, 5)
        out["valid"] = out["valid"] and abs(change) <= max_volume_change
    return out


def shape_change(nominal: trimesh.Trimesh, mesh: trimesh.Trimesh) -> dict:
    """How far a deformed ``mesh`` (the nominal's vertex order and faces) is from the ``nominal`` object.

    Returns:
        ``volume_change``: relative change of the enclosed volume (``-0.12``: 12% smaller), and
        ``max_dihedral_change_deg``: the largest change, over all edges, of the angle between the two
        faces' normals (degrees; a crease the deformation made or flattened).
    """
    v0 = abs(float(nominal.volume))
    nominal_angles = np.asarray(nominal.face_adjacency_angles)
    shape = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(nominal.faces), process=False)
    angles = shape.face_adjacency_angles if np.array_equal(shape.face_adjacency, nominal.face_adjacency) else None
    change = np.degrees(np.abs(np.asarray(angles) - nominal_angles)).max() if angles is not None else float("nan")
    return {"volume_change": round(abs(float(shape.volume)) / v0 - 1.0, 5) if v0 > 0 else None,
            "max_dihedral_change_deg": round(float(change), 2)}
