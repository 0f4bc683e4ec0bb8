"""How faithful a prepared mesh is to its input: volume ratio, two-sided Hausdorff and Chamfer distance.

Distances are point-to-surface (point-cloud-utils' BVH closest points), measured from points sampled on
each surface (area-weighted, fixed seed, plus every vertex, so a moved corner is never missed) to the
other surface. The volume of a closed input is exact (signed tetrahedra); the volume of an open or
multi-body input is the volume where its generalized winding number is above 1/2 (Jacobson et al.
2013), measured on a regular grid: the solid a user means by an almost-closed surface.
"""

from __future__ import annotations

import gpytoolbox
import numpy as np
import point_cloud_utils as pcu
import trimesh

SAMPLES = 20_000  # points sampled on each surface
GRID = 64  # winding-number grid cells along the longest side (open inputs only)


def _closest_distances(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    d, _, _ = pcu.closest_points_on_mesh(np.ascontiguousarray(points, np.float64),
                                         np.ascontiguousarray(vertices, np.float64),
                                         np.ascontiguousarray(faces, np.int32))
    return np.asarray(d, np.float64)


def surface_points(mesh: trimesh.Trimesh, samples: int = SAMPLES, seed: int = 0) -> np.ndarray:
    """``(samples + V', 3)`` points on ``mesh``: area-weighted samples (seeded) and its referenced vertices."""
    points, _ = trimesh.sample.sample_surface(mesh, samples, seed=seed)
    used = np.unique(np.asarray(mesh.faces).ravel())
    return np.concatenate([np.asarray(points), np.asarray(mesh.vertices)[used]])


def closest_points(points: np.ndarray, mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """The closest point of ``mesh``'s surface to each of ``points`` ``(P, 3)``: ``(P, 3)`` points, ``(P,)`` distances."""
    v = np.ascontiguousarray(mesh.vertices, np.float64)
    f = np.ascontiguousarray(mesh.faces, np.int32)
    d, fi, bc = pcu.closest_points_on_mesh(np.ascontiguousarray(points, np.float64), v, f)
    return np.asarray(pcu.interpolate_barycentric_coords(f, fi, bc, v)), np.asarray(d)


def enclosed_volume(mesh: trimesh.Trimesh, grid: int = GRID) -> float:
    """Volume enclosed by ``mesh`` (its units cubed): exact when it is closed, else by winding number > 1/2.

    Args:
        mesh: any triangle mesh (open, several bodies, overlapping bodies).
        grid: cells along the longest bounding-box side for the winding-number estimate.
    """
    if mesh.is_watertight and mesh.is_winding_consistent:
        return abs(float(mesh.volume))
    lo, hi = np.asarray(mesh.bounds, np.float64)
    step = float((hi - lo).max()) / grid
    axes = [lo[i] + step * (np.arange(max(1, int(np.ceil((hi[i] - lo[i]) / step)))) + 0.5) for i in range(3)]
    query = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    winding = gpytoolbox.fast_winding_number(query, np.asarray(mesh.vertices, np.float64),
                                             np.asarray(mesh.faces, np.int64))
    return float((np.abs(winding) > 0.5).sum()) * step ** 3


def measure(reference: trimesh.Trimesh, result: trimesh.Trimesh, mm_per_unit: float,
            reference_volume: float | None = None, samples: int = SAMPLES) -> dict:
    """Compare the mesh GRT will deform with the input surface it came from.

    Args:
        reference: the input surface (mesh units); may be open or have several bodies.
        result: the prepared, closed mesh (mesh units).
        mm_per_unit: millimetres per mesh unit (1000 for meters; ``1000 * object_scale`` for a file).
        reference_volume: the input's volume if already known (mesh units cubed), else measured.
        samples: points sampled on each surface.

    Returns:
        ``volume_ratio`` (result / input volume), ``hausdorff_mm`` (max over both directions of the
        point-to-surface distance), ``chamfer_mm`` (mean of the two directions' mean distances),
        ``input_to_result_mm`` and ``result_to_input_mm`` (each direction's max), ``samples``, and
        ``volume_estimated`` (the input is open and ``reference_volume`` not given: its volume is the
        winding-number grid estimate of :func:`enclosed_volume`, a few percent off), and
        ``inner_input_share``: the share of the input's points left out of the input-to-result direction
        because they lie inside the input's own solid (faces between touching bodies, the underside of a
        can's lid), which no closed solid can keep on its surface.
    """
    points = surface_points(reference, samples, seed=0)
    inner = np.zeros(len(points), bool)
    if not (reference.is_watertight and len(reference.split(only_watertight=False)) == 1):
        inner = _inner(points, reference)  # an open or multi-body input: its faces inside its own solid
    to_result = _closest_distances(points[~inner], result.vertices, result.faces)
    to_input = _closest_distances(surface_points(result, samples, seed=1), reference.vertices, reference.faces)
    estimated = reference_volume is None and not (reference.is_watertight and reference.is_winding_consistent)
    ref_volume = enclosed_volume(reference) if reference_volume is None else reference_volume
    ratio = abs(float(result.volume)) / ref_volume if ref_volume > 0 else float("nan")
    return {"volume_ratio": round(ratio, 5),
            "hausdorff_mm": round(float(max(to_result.max(), to_input.max())) * mm_per_unit, 4),
            "chamfer_mm": round(float(to_result.mean() + to_input.mean()) / 2 * mm_per_unit, 4),
            "input_to_result_mm": round(float(to_result.max()) * mm_per_unit, 4),
            "result_to_input_mm": round(float(to_input.max()) * mm_per_unit, 4),
            "samples": samples, "inner_input_share": round(float(inner.mean()), 4), "volume_estimated": estimated}


def _inner(points: np.ndarray, reference: trimesh.Trimesh) -> np.ndarray:
    """Which of ``points`` (on ``reference``) lie inside ``reference``'s own solid (winding number > 3/4: a face
    between two touching bodies, a lid's underside inside a closed can); the outer surface has 1/2."""
    winding = gpytoolbox.fast_winding_number(np.asarray(points, np.float64), np.asarray(reference.vertices, np.float64),
                                             np.asarray(reference.faces, np.int64))
    return np.abs(winding) > 0.75


def unchanged(samples: int = 0) -> dict:
    """The figures of a mesh whose surface was not moved (only exact repairs, or none)."""
    return {"volume_ratio": 1.0, "hausdorff_mm": 0.0, "chamfer_mm": 0.0, "input_to_result_mm": 0.0,
            "result_to_input_mm": 0.0, "samples": samples, "inner_input_share": 0.0, "volume_estimated": False}
