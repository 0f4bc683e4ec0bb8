"""Mesh loading, validation and repair, unit-cube normalization and Procrustes alignment.

GRT's method assumes watertight, manifold triangle meshes (paper, lines 187-189). Every mesh that
enters the system goes through :func:`load_mesh` (a built-in object name or a file path) or
:func:`prepare_mesh` (an in-memory mesh): problems are repaired when that is safe and recorded in
``mesh.metadata["grt_repairs"]``, or rejected with a :class:`~grt.geometry.validation.MeshError` that
names the problem and the fix. A mesh is never silently used as it came.
"""

from __future__ import annotations

import hashlib
import logging
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import trimesh

from grt.geometry import fidelity
from grt.geometry.indices import file_vertices
from grt.geometry.prepare import (
    MeshSettings,
    Solid,
    fix_flat_faces,
    remesh,
    remesh_decision,
    say_step,
    solidify,
    target_faces,
)
from grt.geometry.quality import nominal_crossings
from grt.geometry.validation import MeshError, mesh_problems
from grt.objects import UnknownObjectError, get_object, list_objects

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".glb", ".gltf", ".off")
log = logging.getLogger("grt.mesh")


# --------------------------------------------------------------------------------------- loading
def load_mesh(spec: str | Path, repair: bool = True, components: str | None = None,
              scale: float = 1.0, settings=None) -> trimesh.Trimesh:
    """Resolve a built-in object name or a mesh file into a validated mesh in meters.

    Args:
        spec: a built-in object name (``grt.objects.list_objects()``) or a path to an OBJ, STL, PLY,
            GLB/GLTF or OFF file (meters).
        repair: fix what can be fixed safely (see :func:`prepare_mesh`); ``False`` rejects instead.
        components: policy for separate bodies (``None``: ``settings.components``, default ``"union"``),
            see :func:`prepare_mesh`.
        scale: meters per file unit, applied after validation (the apps' ``object_scale``; 0.001 for a
            mesh in millimetres). Vertex order and faces are kept.
        settings: a :class:`grt.geometry.prepare.MeshSettings` (remeshing, fidelity tolerance); ``None``:
            defaults (no remeshing of a valid mesh, so its vertices are the file's).

    Returns:
        A watertight, manifold, consistently outward-oriented ``trimesh.Trimesh``;
        ``mesh.metadata["grt_repairs"]`` lists what was repaired, ``mesh.metadata["grt_source"]``
        where it came from, ``mesh.metadata["grt_prepare"]`` the whole preparation (repairs, remesh
        decision, fidelity figures in mm, timings in s; see :func:`grt.geometry.prepare.describe`).

    Raises:
        MeshError: unreadable, empty or unusable file (the message names the problem and the fix).
        grt.objects.UnknownObjectError: neither a built-in name nor an existing file.
    """
    start = time.perf_counter()
    read_as = None  # vertices of a file as read
    text = str(spec)
    path = Path(text).expanduser()
    if text in list_objects():
        mesh = get_object(text)
        source = f"builtin:{text}"
    elif path.is_file():
        mesh = _read_file(path)
        source = str(path)
        read_as = len(mesh.vertices)
    elif path.is_dir():
        raise MeshError(_directory_message(text, path))
    elif path.suffix.lower() in MESH_SUFFIXES or "/" in text:
        raise MeshError(f"mesh file not found: {text!r}. Give an existing path or one of the built-in "
                        f"objects: {', '.join(list_objects())}.")
    else:
        raise UnknownObjectError(text)
    if not (isinstance(scale, (int, float)) and not isinstance(scale, bool) and np.isfinite(scale) and scale > 0):
        raise MeshError(f"object_scale={scale!r}: it must be a finite number > 0 (meters per mesh unit, "
                        "e.g. 0.001 for a mesh in millimetres)")
    try:
        mesh = prepare_mesh(mesh, repair=repair, components=components, settings=settings,
                            builtin=source.startswith("builtin:"), mm_per_unit=1000.0 * float(scale))
    except MeshError as exc:
        raise MeshError(f"{text}: {exc}") from None
    if scale != 1.0:  # 1.0 keeps the vertices bit-identical (mesh hashes of runs from before object_scale)
        mesh.vertices = np.asarray(mesh.vertices) * float(scale)
    mesh.metadata["grt_source"] = source
    prep = mesh.metadata["grt_prepare"]
    if path.is_file() and read_as is not None:
        _note_reading(path, read_as, mesh)
    prep.update(source=source, scale=float(scale))
    prep["timings_s"]["total"] = round(time.perf_counter() - start, 4)  # reading the file included
    return mesh


def _directory_message(text: str, path: Path) -> str:
    """The one line for a folder given as the object: say it is one, and name mesh files in it."""
    try:
        found = sorted(p.name for p in path.iterdir() if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
    except OSError:
        found = []
    inside = (f"; it holds {', '.join(found[:3])}{' ...' if len(found) > 3 else ''}: give one of them, e.g. "
              f"object={path / found[0]}") if found else "; give a mesh file (one of " + \
        f"{', '.join(sorted(MESH_SUFFIXES))}) or a built-in object's name"
    return f"object={text} is a directory, not a mesh file{inside}"


def prepare_report(spec: str | Path, scale: float = 1.0, **settings) -> dict:
    """Load one object and return a flat row for a measurement table (``python -m grt.bench meshes``).

    Args:
        spec: a built-in object name or a mesh file path.
        scale: meters per mesh unit (``object_scale``).
        **settings: :class:`~grt.geometry.prepare.MeshSettings` fields; ``remesh`` defaults to ``"auto"``
            here (the apps' setting).

    Returns:
        ``object, input_faces, prepared_faces, prepared_vertices, repairs (list), remesh (decision),
        volume_ratio, hausdorff_mm, chamfer_mm, prepare_s`` and ``timings_s``; or ``object, error`` when
        the mesh is refused (the one-line message).
    """
    settings.setdefault("remesh", "auto")
    start = time.perf_counter()
    try:
        mesh = load_mesh(spec, scale=scale, settings=MeshSettings(**settings))
    except MeshError as exc:
        return {"object": str(spec), "error": str(exc), "prepare_s": round(time.perf_counter() - start, 3)}
    prep = mesh.metadata["grt_prepare"]
    return {"object": str(spec), "input_faces": prep["input"]["faces"], "prepared_faces": prep["output"]["faces"],
            "prepared_vertices": prep["output"]["vertices"], "repairs": prep["repairs"],
            "remesh": prep["remesh"]["decision"], **{k: prep["fidelity"][k] for k in
                                                      ("volume_ratio", "hausdorff_mm", "chamfer_mm")},
            "prepare_s": prep["timings_s"]["total"], "timings_s": prep["timings_s"]}


# An object a tabletop robot handles: at most 1 m and at least 5 mm along its largest side (meters).
OBJECT_SIZE_M = (0.005, 1.0)
_UNITS = ((0.001, "millimetres"), (0.01, "centimetres"))


def check_object_size(mesh: trimesh.Trimesh, key: str = "object_scale") -> None:
    """Refuse, before any simulation, an object whose size says its mesh is not in meters.

    Args:
        mesh: the loaded object (meters, after ``key`` was applied).
        key: the config key that scales the mesh, named in the message.

    Raises:
        MeshError: the largest bounding-box side is above 1 m or below 5 mm; names the likely unit and
            the value of ``key`` that fixes it.
    """
    extents = np.asarray(mesh.extents, np.float64)
    size = float(extents.max())
    low, high = OBJECT_SIZE_M
    if low <= size <= high:
        return
    box = " x ".join(f"{e:.3g}" for e in extents)
    if size > high:  # the unit whose meters land nearest a 10 cm object (in log scale)
        factor, unit = min(_UNITS, key=lambda u: abs(np.log10(size * u[0] / 0.1)))
        raise MeshError(f"the object is {size:.3g} m across (bounding box {box} m), more than {high:g} m: a mesh in "
                        f"{unit}? set {key}={factor:g} (meters per mesh unit)")
    factor = 10.0 ** round(np.log10(0.1 / size)) if size > 0 else 1000.0
    raise MeshError(f"the object is {size * 1000:.3g} mm across (bounding box {box} m), less than {low * 1000:g} mm: "
                    f"a mesh in other units than meters (or scaled twice)? set {key}={factor:g} "
                    f"(meters per mesh unit; it makes the object {size * factor:.3g} m across)")


def _note_reading(path: Path, read_as: int, mesh: trimesh.Trimesh) -> None:
    """Record, first among the repairs, that reading the file already changed its vertex list."""
    if path.suffix.lower() != ".obj":
        return
    written = len(file_vertices(path))
    if written != read_as:
        note = (f"read the file's {written} vertices as {read_as} (unreferenced vertices dropped, vertices on "
                "texture seams split; vertex indices are carried by position, see grt.geometry.indices)")
        mesh.metadata["grt_repairs"].insert(0, note)


def _read_file(path: Path) -> trimesh.Trimesh:
    if path.stat().st_size == 0:
        raise MeshError(f"{path}: the file is empty. Export the mesh again (OBJ/STL/PLY/GLB).")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unsupported mesh format {path.suffix!r}; use one of {MESH_SUFFIXES}.")
    size = path.stat().st_size
    if size > 20e6:  # ~400k faces of binary STL: reading alone takes a while
        log.info("reading %s (%.0f MB)", path, size / 1e6)
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds of errors on corrupt input
        raise MeshError(f"{path}: could not be read as a mesh ({type(exc).__name__}: {exc}). "
                        "Check that the file is a valid, uncorrupted mesh file.") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"{path}: contains no triangles. Export a triangle mesh (not a point cloud).")
    return loaded


# ------------------------------------------------------------------------------------- repair
def prepare_mesh(mesh: trimesh.Trimesh, repair: bool = True, components: str | None = None,
                 settings=None, builtin: bool = False, mm_per_unit: float = 1000.0) -> trimesh.Trimesh:
    """Validate an in-memory mesh, repair it faithfully, remesh it if asked, and check what changed.

    The steps are those of :mod:`grt.geometry.prepare`: exact clean-up (merge duplicate vertices, drop
    degenerate/duplicate faces and unreferenced vertices, consistent outward winding, 3-4 vertex holes);
    overlapping closed bodies united (manifold3d); an open surface closed by a watertight manifold
    conversion (point-cloud-utils); isotropic remeshing (gpytoolbox); then a fidelity check against the
    input. Each repair is recorded in ``metadata["grt_repairs"]``, the figures in ``metadata["grt_prepare"]``.

    Args:
        mesh: input mesh (not modified).
        repair: ``False`` raises on the first problem instead of repairing.
        components: separate bodies: ``"union" | "largest" | "error" | "keep"`` (``None``: ``settings``'s,
            default ``"union"``: overlapping bodies united, bodies apart refused).
        settings: a :class:`grt.geometry.prepare.MeshSettings` (``None``: defaults, no remeshing).
        builtin: the mesh is a built-in object (``remesh="auto"`` keeps it as it is).
        mm_per_unit: millimetres per mesh unit, for the fidelity figures and tolerance (1000: meters).

    Returns:
        A new valid mesh.

    Raises:
        MeshError: NaN/inf vertices, an empty mesh, a mesh that cannot be repaired, separate bodies, or a
            repair that changed the object more than ``settings`` allow.
    """
    settings = settings or MeshSettings()
    if components is not None and components != settings.components:
        settings = replace(settings, components=components)
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise MeshError("the mesh is empty (no faces). Export a closed triangle mesh.")
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError("the mesh has NaN or infinite vertex coordinates; it cannot be repaired "
                        "automatically. Re-export it from your modelling tool.")
    _check_has_volume(mesh)
    t0 = time.perf_counter()
    repairs: list[str] = []
    out = trimesh.Trimesh(vertices=np.array(mesh.vertices, np.float64), faces=np.array(mesh.faces),
                          process=False)
    problems = mesh_problems(out)
    if problems and not repair:
        raise MeshError(f"invalid mesh: {'; '.join(problems)}. Repair it (e.g. pymeshfix, MeshLab) "
                        "or load it with repair=True.")
    solid = Solid(out, out)
    edge = settings.edge_length * float(np.linalg.norm(out.extents))  # target edge length, mesh units
    say_step(len(mesh.faces), "it is cleaned up, remeshed if too fine (mesh.remesh=%s, to about %d faces) and "
             "compared with the input (fidelity); each step is said as it starts", settings.remesh,
             target_faces(out, edge))
    if problems:
        say_step(len(mesh.faces), "cleaning up (found: %s)", "; ".join(problems)[:200])
        solid = solidify(_basic_cleanup(out, repairs), settings.components, repairs, edge,
                         settings.watertight_resolution)
    out = solid.mesh
    t1 = time.perf_counter()
    remeshed, decision = remesh_decision(out, settings, edge, builtin, solid.must_remesh)
    if remeshed:
        avoid = ("set mesh.remesh=off: your mesh is closed and is then used as it is" if not solid.moved
                 and not solid.must_remesh else "close the mesh in a modelling tool, or set another mesh.edge_length")
        out = remesh(out, edge, repairs, fix=avoid)
    remaining = mesh_problems(out)
    if settings.components == "keep":
        remaining = [p for p in remaining if "connected components" not in p]
    if remaining:
        raise MeshError(f"mesh could not be repaired: {'; '.join(remaining)}. The method needs a "
                        "watertight manifold mesh: repair it in a modelling tool (e.g. MeshLab, "
                        "Blender's 3D-print toolbox) and load it again.")
    t2 = time.perf_counter()
    exact = not (solid.moved or remeshed)
    volume = solid.reference_volume if solid.reference_volume is not None else _closed_volume(mesh)
    if not exact:
        say_step(len(mesh.faces), "measuring the fidelity (Hausdorff and Chamfer distance, volume) of the %d-face "
                 "result against the input", len(out.faces))
    figures = fidelity.unchanged() if exact else fidelity.measure(solid.reference, out, mm_per_unit, volume)
    t3 = time.perf_counter()
    _check_fidelity(figures, settings, repairs, out, mm_per_unit,
                    cause="remesh" if not solid.moved and not solid.must_remesh else "close", problems=problems,
                    faces=len(mesh.faces))
    crossings = len(nominal_crossings(out))
    out.metadata["grt_repairs"] = repairs
    out.metadata["grt_prepare"] = {
        "source": "mesh", "builtin": builtin, "settings": asdict(settings),
        "input": {"vertices": len(mesh.vertices), "faces": len(mesh.faces), "problems": problems},
        "output": {"vertices": len(out.vertices), "faces": len(out.faces), "self_intersections": crossings},
        "repairs": repairs, "exact": exact,
        "remesh": {"done": remeshed, "decision": decision, "edge_length_mm": round(edge * mm_per_unit, 4)},
        "fidelity": figures, "tolerance": {"fidelity_mm": settings.fidelity_mm, "volume_tol": settings.volume_tol},
        "timings_s": {"repair": round(t1 - t0, 4), "remesh": round(t2 - t1, 4), "fidelity": round(t3 - t2, 4),
                      "total": round(t3 - t0, 4)},
    }
    return out


def _check_has_volume(mesh: trimesh.Trimesh) -> None:
    """Refuse a flat input (every vertex in one plane: a single triangle, a sheet): it encloses no volume."""
    v = np.asarray(mesh.vertices, np.float64)
    sv = np.linalg.svd(v - v.mean(0), compute_uv=False) if len(v) >= 3 else np.zeros(3)
    if len(sv) < 3 or sv[2] <= 1e-9 * max(sv[0], 1e-300):
        raise MeshError(f"the mesh has no volume: all its {len(v)} vertices ({len(mesh.faces)} faces) lie in one "
                        f"{'line' if len(sv) < 2 or sv[1] <= 1e-9 * max(sv[0], 1e-300) else 'plane'} (a flat sheet). "
                        "GRT deforms solid objects: give a closed mesh of the whole object")


def _closed_volume(mesh: trimesh.Trimesh) -> float | None:
    """The exact enclosed volume of the input as given when it is closed (duplicate vertices merged; zero-area
    faces add nothing), else None (the fidelity then estimates it and says so)."""
    merged = trimesh.Trimesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces), process=False)
    merged.merge_vertices()
    if merged.is_watertight and merged.is_winding_consistent:
        return abs(float(merged.volume))
    return None


def _accept(value: float) -> str:
    """A setting value just above a measured ``value`` (two significant digits, rounded up)."""
    digits = 10.0 ** (np.floor(np.log10(value)) - 1) if value > 0 else 1.0
    return f"{np.ceil(value * 1.02 / digits) * digits:.2g}"


def _check_fidelity(figures: dict, settings, repairs: list[str], out: trimesh.Trimesh, mm_per_unit: float,
                    cause: str = "close", problems: list[str] | None = None, faces: int = 0) -> None:
    """Refuse a prepared mesh further from its input than ``settings`` allow: one line naming the step that
    changed it (GRT's remeshing of a closed input, or the closing of an open one) and fixes that work."""
    ratio, dist = figures["volume_ratio"], figures["hausdorff_mm"]
    if not np.isfinite(ratio):
        raise MeshError("the input encloses no volume (an open sheet, or a surface without inside): GRT deforms "
                        "solid objects: give a closed mesh of the whole object")
    far, swollen = dist > settings.fidelity_mm, not abs(ratio - 1.0) <= settings.volume_tol
    if not (far or swollen):
        return
    scaled = out.copy()
    scaled.vertices = np.asarray(scaled.vertices) * (mm_per_unit / 1000.0)
    check_object_size(scaled)  # a unit mistake is the likelier cause (and its figures are 1000x off)
    what, accept = [], []
    if far:
        what.append(f"the surface moved up to {dist:.3g} mm (mesh.fidelity_mm={settings.fidelity_mm:g})")
        accept.append(f"mesh.fidelity_mm={_accept(dist)}")
    if swollen:
        estimate = " (an estimate: the input is open, its volume is measured on a winding-number grid)" \
            if figures.get("volume_estimated") else ""
        what.append(f"the volume changed x{ratio:.3f}{estimate} (mesh.volume_tol={settings.volume_tol:g})")
        accept.append(f"mesh.volume_tol={_accept(abs(ratio - 1.0))}")
    steps = "; ".join(repairs) or "none"
    if cause == "remesh":
        raise MeshError(f"GRT's own remeshing step changed the object more than allowed: {' and '.join(what)}; "
                        f"your mesh is closed and was kept as it is until that step. Steps: {steps}. Fix: set "
                        f"mesh.remesh=off (GRT then uses your mesh's own triangles"
                        + (f"; {faces} of them make every step slow: or decimate it to ~20000 faces in a modelling "
                           "tool" if faces > 200_000 else "")
                        + f"), or accept the change with {' '.join(accept)}")
    given = f" ({'; '.join(problems)})" if problems else ""
    if ratio < 0.5:  # a shell around an open sheet (an open cup), not the solid the user means
        raise MeshError(f"the input is not one closed solid{given}, and GRT could not close it into a solid: "
                        f"{' and '.join(what)}. Steps: {steps}. Fix: close the mesh in a modelling tool (MeshLab: "
                        "Close Holes; Blender's 3D-print toolbox) so GRT uses it as it is")
    raise MeshError(f"the input is not one closed solid{given}, and closing it changed the object more than allowed: "
                    f"{' and '.join(what)}. Steps: {steps}. Fix: close the mesh in a modelling tool (MeshLab: "
                    f"Close Holes; Blender's 3D-print toolbox) so GRT uses it as it is, or accept the change with "
                    f"{' '.join(accept)}")


def _basic_cleanup(mesh: trimesh.Trimesh, repairs: list[str]) -> trimesh.Trimesh:
    n_v, n_f = len(mesh.vertices), len(mesh.faces)
    mesh.remove_unreferenced_vertices()
    if len(mesh.vertices) < n_v:
        repairs.append(f"removed {n_v - len(mesh.vertices)} unreferenced vertices")
    n_v = len(mesh.vertices)
    mesh.merge_vertices()
    if len(mesh.vertices) < n_v:
        repairs.append(f"merged {n_v - len(mesh.vertices)} duplicate vertices")
    mesh = _collapse_flat_faces(mesh, repairs)
    keep = mesh.nondegenerate_faces(height=1e-12)
    mesh.update_faces(keep)
    mesh.update_faces(mesh.unique_faces())
    if len(mesh.faces) < n_f:
        repairs.append(f"removed {n_f - len(mesh.faces)} degenerate or duplicate faces")
    n_v = len(mesh.vertices)
    mesh.remove_unreferenced_vertices()
    if len(mesh.vertices) < n_v:
        repairs.append(f"removed {n_v - len(mesh.vertices)} vertices of removed faces")
    return mesh


def _collapse_flat_faces(mesh: trimesh.Trimesh, repairs: list[str]) -> trimesh.Trimesh:
    """A closed surface's zero-area faces are part of its closure (a T-junction along a seam): collapse them
    in place (:func:`grt.geometry.prepare.fix_flat_faces`) instead of deleting them, which would open it."""
    flat = int(len(mesh.faces) - mesh.nondegenerate_faces(height=1e-12).sum())
    if not flat or not mesh.is_watertight:
        return mesh
    fixed = fix_flat_faces(mesh)
    left = fixed.metadata.pop("grt_flat_faces_left")
    fixed.metadata.pop("grt_flat_faces_fixed")
    moved = fixed.metadata.pop("grt_flat_faces_moved")
    if not fixed.is_watertight or left == flat:
        return mesh  # nothing gained: the zero-area faces are removed below and the surface closed again
    how = (f"vertices moved up to {moved:.3g} mesh units along their edges" if moved > 0
           else "the surface did not move")
    repairs.append(f"collapsed {flat - left} of {flat} zero-area faces of the closed surface in place (coincident "
                   f"vertices merged, faces lying along a neighbour's edge flipped into it): {how}, and it stays closed")
    return fixed


def mesh_hash(vertices: np.ndarray, faces: np.ndarray) -> str:
    """Content hash of a mesh (vertex coordinates rounded to 1e-9 and faces); 16 hex digits."""
    h = hashlib.sha256()
    h.update(np.round(np.asarray(vertices, np.float64), 9).tobytes())
    h.update(np.asarray(faces, np.int64).tobytes())
    return h.hexdigest()[:16]


# --------------------------------------------------------------------------------- normalization
@dataclass(frozen=True)
class UnitCubeFrame:
    """Map between metric coordinates and the centered unit cube the deformation works in.

    ``unit = (metric - center) / scale``; ``scale`` (meters per unit) is the largest bounding-box
    extent, so the mesh fits ``[-0.5, 0.5]^3``.
    """

    center: np.ndarray  # (3,) meters
    scale: float  # meters per unit-cube unit

    @classmethod
    def fit(cls, vertices: np.ndarray) -> UnitCubeFrame:
        lo, hi = np.min(vertices, axis=0), np.max(vertices, axis=0)
        scale = float(np.max(hi - lo))
        if not scale > 0:
            raise MeshError("the mesh has zero extent; cannot normalize it")
        return cls(center=(lo + hi) / 2.0, scale=scale)

    def to_unit(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3)`` meters -> unit-cube units."""
        return (np.asarray(points) - self.center) / self.scale

    def to_metric(self, points: np.ndarray) -> np.ndarray:
        """``(..., 3)`` unit-cube units -> meters."""
        return np.asarray(points) * self.scale + self.center


def procrustes(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthogonal Procrustes (Kabsch): the rigid motion that best maps ``source`` onto ``target``.

    Args:
        source: ``(..., K, 3)`` points (e.g. anchors of the deformed mesh).
        target: ``(K, 3)`` or ``(..., K, 3)`` corresponding points (the nominal anchors).

    Returns:
        ``R`` ``(..., 3, 3)`` proper rotation and ``t`` ``(..., 3)`` with ``source @ R.T + t ~ target``.
    """
    source = np.asarray(source, np.float64)
    target = np.broadcast_to(np.asarray(target, np.float64), source.shape)
    mu_s, mu_t = source.mean(-2, keepdims=True), target.mean(-2, keepdims=True)
    H = np.swapaxes(source - mu_s, -1, -2) @ (target - mu_t)  # (..., 3, 3)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, -1, -2) @ np.swapaxes(U, -1, -2)))
    D = np.zeros(H.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    R = np.swapaxes(Vt, -1, -2) @ D @ np.swapaxes(U, -1, -2)
    t = mu_t[..., 0, :] - (mu_s @ np.swapaxes(R, -1, -2))[..., 0, :]
    return R, t


def align_to_anchors(vertices: np.ndarray, anchors: np.ndarray, nominal_anchor_pos: np.ndarray) -> np.ndarray:
    """Rigidly align deformed meshes to the nominal one on the anchor correspondences.

    Args:
        vertices: ``(..., V, 3)`` deformed vertices.
        anchors: ``(K,)`` anchor vertex indices (K >= 3 for a unique rotation).
        nominal_anchor_pos: ``(K, 3)`` anchor positions on the nominal mesh, same units.

    Returns:
        ``(..., V, 3)`` aligned vertices.
    """
    R, t = procrustes(vertices[..., anchors, :], nominal_anchor_pos)
    if vertices.ndim == 2:
        return vertices @ R.T + t
    # A population one mesh at a time into one array: the broadcast (N, V, 3) @ (N, 3, 3) product took
    # 4-5 ms for ten meshes of 5k vertices where this takes ~1 ms (python -m grt.bench deform).
    flat = vertices.reshape(-1, *vertices.shape[-2:])
    rot, shift = R.reshape(-1, 3, 3), t.reshape(-1, 3)
    out = np.empty(flat.shape)
    for n in range(len(flat)):
        np.matmul(flat[n], rot[n].T, out=out[n])
        out[n] += shift[n]
    return out.reshape(vertices.shape)
