"""The input pipeline: from a user's mesh to the closed, uniformly meshed solid GRT deforms, checked for fidelity.

Steps (each recorded in ``mesh.metadata["grt_repairs"]``, the figures in ``mesh.metadata["grt_prepare"]``):

1. Exact clean-up (:func:`grt.geometry.mesh.prepare_mesh`): merge duplicate vertices, drop degenerate or
   duplicate faces and unreferenced vertices, make the winding consistent and outward. The surface does
   not move.
2. One solid (:func:`solidify`): closed bodies that overlap are united (manifold3d's exact boolean
   union); an open surface (holes larger than a quad, a can whose lid and wall are separate open sheets)
   is closed by point-cloud-utils' watertight manifold conversion (Huang et al. 2018) and projected back
   onto the input. Bodies that stay separate (two spheres, two cubes touching along an edge) are refused
   with a message, or, with ``components="largest"``, all but the largest are dropped and reported.
3. Isotropic remeshing (gpytoolbox's ``remesh_botsch``) to a target edge length that is a fraction of the
   bounding-box diagonal, after a quadric decimation of very fine inputs. ``remesh="auto"`` remeshes a
   mesh file that is too coarse (most of its area in triangles with an edge over 3x the target) or too
   fine (over 4x the target's face count), any mesh with slivers (over 1% of its faces with longest
   edge² > 10 x twice the area: their normals flip under deformation, so CrashShapes would hold folded
   faces; of the built-ins, ``mug`` and ``round_peg``), and always the output of step 2; other built-in
   objects are kept as they are.
4. Fidelity (:mod:`grt.geometry.fidelity`): volume ratio, two-sided Hausdorff and Chamfer distance (mm)
   between the input surface and the result; above ``fidelity_mm`` or ``volume_tol`` a one-line
   :class:`~grt.geometry.validation.MeshError` says what changed and how to fix it.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, fields

import gpytoolbox
import manifold3d
import numpy as np
import point_cloud_utils as pcu
import trimesh

from grt.geometry import fidelity
from grt.geometry.validation import MeshError, manifold3d_accepts

REMESH_MODES = ("auto", "on", "off")
COMPONENT_POLICIES = ("union", "largest", "error", "keep")
FINE_FACTOR = 4.0  # "too fine": more faces than this times the target's face count
COARSE_EDGE, COARSE_AREA = 3.0, 0.5  # "coarse": over half the area in triangles with an edge > 3x the target
REMESH_ITERATIONS = 10
# "slivers": more than 1% of the faces with longest edge² / (2 area) > 10 (an equilateral triangle: 1.15).
# A sliver's normal flips under a small smooth deformation, so its CrashShapes would hold folded faces.
SLIVER_ASPECT, SLIVER_SHARE = 10.0, 0.01
JOIN_GROWTH = 0.1  # bodies closer than 2x this times the target edge are joined
CREASE_DEG = 30.0  # dihedral angle of a sharp edge kept by the remeshing
DECIMATE_VOLUME_TOL = 0.005  # a decimation stage that changes the volume by more than 0.5% is not kept
# An input above this many faces says each step of its preparation as it starts (a 2M-face scan took 5.5 min
# in silence: reading, clean-up, decimation stages, remeshing, the fidelity measure each take a while).
LARGE_FACES = 100_000
log = logging.getLogger("grt.mesh")


def say_step(faces: int, text: str, *args) -> None:
    """Log (INFO, ``grt.mesh``) a step of preparing an input of ``faces`` faces as it starts, if it is large."""
    if faces > LARGE_FACES:
        log.info("preparing a %d-face mesh: " + text, faces, *args)


@dataclass(frozen=True)
class MeshSettings:
    """How a mesh is prepared: the ``mesh`` block of ``conf/run.yaml``, ``evaluate.yaml`` and ``select.yaml``.

    Attributes:
        remesh: ``"auto"`` (mesh files that are too coarse or too fine, and converted surfaces), ``"on"``
            (every mesh, built-ins too) or ``"off"`` (only a converted surface, which must be remeshed).
        edge_length: target edge length as a fraction of the bounding-box diagonal (0.02: ~3 mm on a mug).
        fidelity_mm: largest two-sided Hausdorff distance allowed between input and prepared mesh (mm).
        volume_tol: largest relative change of the enclosed volume allowed (0.05: 5%).
        components: separate bodies after union: ``"union"`` refuses them, ``"largest"`` keeps the largest
            (the others are reported), ``"keep"`` keeps all (each needs its own anchor), ``"error"``
            refuses any input with more than one body.
        watertight_resolution: octree leaves of the watertight conversion (point-cloud-utils' default).
    """

    remesh: str = "off"
    edge_length: float = 0.02
    fidelity_mm: float = 2.0
    volume_tol: float = 0.05
    components: str = "union"
    watertight_resolution: int = 20_000

    def __post_init__(self):
        if self.remesh not in REMESH_MODES:
            raise MeshError(f"mesh.remesh={self.remesh!r}: use one of {', '.join(REMESH_MODES)}")
        if self.components not in COMPONENT_POLICIES:
            raise MeshError(f"mesh.components={self.components!r}: use one of {', '.join(COMPONENT_POLICIES)}")
        for key, high in (("edge_length", 0.5), ("fidelity_mm", float("inf")), ("volume_tol", float("inf"))):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= high:
                raise MeshError(f"mesh.{key}={value!r}: it must be a number > 0"
                                + (f" and <= {high:g} (a fraction of the bounding-box diagonal)" if high < 1 else ""))

    @classmethod
    def from_config(cls, node) -> MeshSettings:
        """Settings from a config mapping (``cfg.mesh``); ``None`` gives the defaults (a run from before the key)."""
        if node is None:
            return cls()
        known = {f.name for f in fields(cls)}
        given = dict(node.items())
        unknown = sorted(set(given) - known)
        if unknown:
            raise MeshError(f"mesh.{unknown[0]} is not a mesh setting; the keys are {', '.join(sorted(known))}")
        return cls(**given)


@dataclass
class Solid:
    """Step 2's result: the closed mesh, what to measure it against, and what happened."""

    mesh: trimesh.Trimesh
    reference: trimesh.Trimesh  # the input surface (mesh units)
    reference_volume: float | None = None  # None: measured from ``reference``
    moved: bool = False  # the surface changed (else fidelity is exact)
    must_remesh: str = ""  # why remeshing is needed whatever the setting


def _to_manifold(mesh: trimesh.Trimesh):
    return manifold3d.Manifold(manifold3d.Mesh64(vert_properties=np.asarray(mesh.vertices, np.float64),
                                                 tri_verts=np.asarray(mesh.faces, np.uint32)))


def _from_manifold(solid) -> trimesh.Trimesh:
    m = solid.to_mesh64()
    return trimesh.Trimesh(np.asarray(m.vert_properties)[:, :3], np.asarray(m.tri_verts, np.int64), process=False)


def bodies_of(mesh: trimesh.Trimesh) -> list[trimesh.Trimesh]:
    """The connected components of ``mesh`` (by shared edges), largest first; nothing else changed.

    (``trimesh.Trimesh.split`` is not used: it also fills small holes, silently.)
    """
    groups = trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)), min_len=1)
    parts = []
    for group in sorted(groups, key=len, reverse=True):
        part = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)[np.sort(group)], process=False)
        part.remove_unreferenced_vertices()
        parts.append(part)
    return parts


def _closed(mesh: trimesh.Trimesh) -> bool:
    return bool(mesh.is_watertight and manifold3d_accepts(mesh))


def _orient(part: trimesh.Trimesh) -> tuple[bool, bool]:
    """Make a closed part's winding consistent and outward; (winding fixed, normals flipped)."""
    rewound = not part.is_winding_consistent
    if rewound:
        trimesh.repair.fix_winding(part)
    inverted = bool(part.volume < 0)
    if inverted:
        part.invert()
    return rewound, inverted


def solidify(mesh: trimesh.Trimesh, components: str, repairs: list[str], edge: float,
             resolution: int = 20_000) -> Solid:
    """Make ``mesh`` (cleaned, mesh units) one closed solid (step 2 of the module docstring).

    Closed bodies that stay apart after their union but nearly touch (every gap <= ``edge``, e.g. the
    hulls of a convex decomposition) are joined by the watertight conversion.

    Raises:
        MeshError: separate bodies under ``components="union"`` or ``"error"``; a conversion that fails.
    """
    parts = bodies_of(mesh)
    if components == "error" and len(parts) > 1:
        raise MeshError(f"the mesh has {len(parts)} separate bodies; GRT deforms one solid. Join them in a "
                        "modelling tool, or set mesh.components=union (unite overlapping bodies) or largest")
    rewound = inverted = 0
    for part in parts:
        if not _closed(part):
            before = len(part.faces)
            trimesh.repair.fill_holes(part)  # only 3- or 4-vertex holes: a flat patch, nothing invented
            if _closed(part):
                repairs.append(f"filled small holes ({len(part.faces) - before} faces added, trimesh)")
        if part.is_watertight:
            fixed = _orient(part)
            rewound, inverted = rewound + fixed[0], inverted + fixed[1]
    for count, what in ((rewound, "made face winding consistent"), (inverted, "flipped inward-facing normals")):
        if count:
            repairs.append(what + (f" on {count} of {len(parts)} bodies" if len(parts) > 1 else ""))
    moved = any(r.startswith("filled") or "moved up to" in r for r in repairs)
    if all(_closed(p) for p in parts):
        if len(parts) == 1 or components == "keep":
            joined = parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)
            return Solid(joined, joined.copy(), moved=moved)
        return _unite(parts, components, repairs, edge, resolution)
    return _convert(mesh, components, repairs, resolution)


def _unite(parts: list[trimesh.Trimesh], components: str, repairs: list[str], edge: float,
           resolution: int) -> Solid:
    union = manifold3d.Manifold.batch_boolean([_to_manifold(p) for p in parts], manifold3d.OpType.Add)
    bodies = sorted(union.decompose(), key=lambda b: -b.volume())
    faces = sum(len(p.faces) for p in parts)
    if len(bodies) == 1:
        out = _from_manifold(union)
        repairs.append(f"united {len(parts)} overlapping bodies into one solid (manifold3d boolean union, "
                       f"{faces} -> {len(out.faces)} faces)")
        return Solid(out, out.copy(), abs(float(union.volume())), moved=False,
                     must_remesh="a boolean union leaves sliver triangles along its intersection curves")
    grow = JOIN_GROWTH * edge
    gaps = [min(b.min_gap(o, 1e9) for o in bodies if o is not b) for b in bodies]
    if max(gaps) < 2 * grow and components != "keep":  # touching or nearly (convex-decomposition hulls)
        grown = [_to_manifold(_grown(_from_manifold(b), grow)) for b in bodies]
        union = manifold3d.Manifold.batch_boolean(grown, manifold3d.OpType.Add)
        if len(union.decompose()) == 1:
            out = _from_manifold(union)
            reference = trimesh.util.concatenate([_from_manifold(b) for b in bodies])
            repairs.append(f"joined {len(bodies)} bodies that touch or nearly touch (gaps up to {max(gaps):.3g} mesh "
                           f"units) by growing each {grow:.3g} mesh units along its normals before the union")
            return Solid(out, reference, sum(abs(b.volume()) for b in bodies), moved=True,
                         must_remesh="a boolean union leaves sliver triangles along its intersection curves")
    kept = _separate_bodies(bodies, components, repairs, "closed bodies")
    if components == "keep":
        return Solid(kept, kept.copy(), moved=False)
    return Solid(kept, kept.copy(), abs(float(kept.volume)), moved=False,
                 must_remesh="" if len(parts) == len(bodies) else "a boolean union leaves sliver triangles")


def _grown(mesh: trimesh.Trimesh, distance: float) -> trimesh.Trimesh:
    """``mesh`` with every vertex moved ``distance`` along its (area-weighted) normal."""
    return trimesh.Trimesh(np.asarray(mesh.vertices) + distance * np.asarray(mesh.vertex_normals), mesh.faces,
                           process=False)


def _separate_bodies(bodies: list, components: str, repairs: list[str], what: str) -> trimesh.Trimesh:
    """Apply the policy to bodies that stay apart; ``bodies`` are manifold3d solids, largest first."""
    gap = min(bodies[0].min_gap(b, 1e9) for b in bodies[1:])
    size = float(np.linalg.norm(np.subtract(*_bounds(bodies[0]))))
    how = (f"{len(bodies)} separate {what} (the nearest {gap / size:.1%} of the largest one's size apart)" if gap > 0
           else f"{len(bodies)} {what} that touch only along an edge or at a point (no shared volume)")
    if components == "union":
        raise MeshError(f"the mesh has {how}: GRT deforms one solid and will not drop a body silently. "
                        "Join them in a modelling tool (make them overlap), or set mesh.components=largest to keep "
                        "the largest (the others are reported)")
    volumes = [b.volume() for b in bodies]
    if components == "keep":
        repairs.append(f"kept {how} as they are (components=keep: each needs its own anchor)")
        return trimesh.util.concatenate([_from_manifold(b) for b in bodies])
    repairs.append(f"DROPPED {len(bodies) - 1} of {how}, keeping the largest "
                   f"({sum(volumes[1:]) / sum(volumes):.1%} of the volume dropped; components=largest)")
    return _from_manifold(bodies[0])


def _bounds(solid) -> tuple[np.ndarray, np.ndarray]:
    box = solid.bounding_box()
    return np.asarray(box[3:6]), np.asarray(box[:3])


def _convert(mesh: trimesh.Trimesh, components: str, repairs: list[str], resolution: int) -> Solid:
    """Close an open or non-manifold surface: watertight manifold conversion, then projection onto the input."""
    v = np.ascontiguousarray(mesh.vertices, np.float64)
    f = np.ascontiguousarray(mesh.faces, np.int32)
    vw, fw = pcu.make_mesh_watertight(v, f, resolution=resolution, seed=0)
    if len(fw) == 0:
        raise MeshError("the watertight conversion produced nothing (a mesh of a few loose triangles?). Provide a "
                        "closed mesh, or close it in a modelling tool (MeshLab: Close Holes)")
    closest, _ = fidelity.closest_points(vw, mesh)  # the conversion offsets the surface by ~a cell: undo it
    out = trimesh.Trimesh(closest, np.asarray(fw, np.int64), process=False)
    if out.volume < 0:
        out.invert()
    repairs.append(f"closed the open or non-manifold surface ({len(bodies_of(mesh))} bodies, "
                   f"{len(mesh.faces)} faces) with point-cloud-utils' watertight manifold conversion "
                   f"(resolution {resolution}), projected back onto the input")
    solid = Solid(out, mesh.copy(), moved=True, must_remesh="the watertight conversion's triangles are uneven")
    bodies = bodies_of(out)
    if len(bodies) > 1 and components != "keep":
        kept = _separate_bodies(sorted((_to_manifold(b) for b in bodies), key=lambda b: -b.volume()),
                                components, repairs, "bodies after closing")
        solid.mesh = kept
    return solid


# ------------------------------------------------------------------------------------- remeshing
def target_faces(mesh: trimesh.Trimesh, edge: float) -> int:
    """Faces of an equilateral triangulation of ``mesh``'s area with edges ``edge`` (mesh units)."""
    return max(1, int(round(float(mesh.area) / (np.sqrt(3.0) / 4.0 * edge * edge))))


def coarse_fraction(mesh: trimesh.Trimesh, edge: float) -> float:
    """Fraction of the area in triangles with an edge longer than ``COARSE_EDGE * edge``."""
    tri = np.asarray(mesh.triangles)
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(1)
    area = np.asarray(mesh.area_faces)
    return float(area[longest > COARSE_EDGE * edge].sum() / max(area.sum(), 1e-300))


def sliver_fraction(mesh: trimesh.Trimesh) -> float:
    """Fraction of the faces whose longest edge² over twice the area exceeds ``SLIVER_ASPECT``."""
    tri = np.asarray(mesh.triangles)
    longest2 = (np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2) ** 2).max(1)
    aspect = longest2 / np.maximum(2.0 * np.asarray(mesh.area_faces), 1e-300)
    return float((aspect > SLIVER_ASPECT).mean())


def remesh_decision(mesh: trimesh.Trimesh, settings: MeshSettings, edge: float, builtin: bool,
                    must: str = "") -> tuple[bool, str]:
    """Whether to remesh and why (a sentence recorded in the report)."""
    if must:
        return True, f"remeshed: {must}"
    if settings.remesh == "off":
        return False, "kept the input's triangles (mesh.remesh=off)"
    if settings.remesh == "on":
        return True, "remeshed (mesh.remesh=on)"
    budget, coarse = target_faces(mesh, edge), coarse_fraction(mesh, edge)
    if not builtin and len(mesh.faces) > FINE_FACTOR * budget:
        return True, f"remeshed: too fine ({len(mesh.faces)} faces, {len(mesh.faces) / budget:.1f}x the target's {budget})"
    if not builtin and coarse > COARSE_AREA:
        return True, (f"remeshed: coarse ({coarse:.0%} of the area in triangles with an edge over "
                      f"{COARSE_EDGE:g}x the target edge)")
    slivers = sliver_fraction(mesh)
    if slivers > SLIVER_SHARE:  # built-in objects too: their CrashShapes would fold
        return True, (f"remeshed: {slivers:.1%} of the faces are slivers (longest edge² > {SLIVER_ASPECT:g} x "
                      "twice the area), whose normals flip under deformation")
    if builtin:
        return False, ("kept a built-in object's triangles (mesh.remesh=auto remeshes built-ins only when they "
                       "have slivers; on: always)")
    return False, (f"kept the input's triangles: uniform enough ({len(mesh.faces)} faces, "
                   f"{len(mesh.faces) / budget:.2f}x the target's; {coarse:.0%} of the area in long triangles)")


def crease_vertices(mesh: trimesh.Trimesh, angle_deg: float = CREASE_DEG) -> np.ndarray:
    """Indices of the vertices on edges whose faces meet at more than ``angle_deg`` (sharp features)."""
    sharp = mesh.face_adjacency_edges[mesh.face_adjacency_angles > np.radians(angle_deg)]
    return np.unique(sharp).astype(np.int32)


def decimate(mesh: trimesh.Trimesh, faces: int, repairs: list[str]) -> trimesh.Trimesh:
    """Quadric decimation of a closed ``mesh`` towards ``faces`` faces, in halving stages that keep its volume.

    One aggressive pass can collapse whole regions (a 1.5 M-face UV sphere, whose poles are 1000-triangle
    fans, shrank to 0.56 of its volume). Each stage halves the face count and is kept only while the mesh
    stays closed and its volume within ``DECIMATE_VOLUME_TOL`` of the input's; the remeshing then starts
    from the last good stage (more faces, slower, but the same object). What happened is recorded.
    """
    volume = abs(float(mesh.volume))
    current, stop = mesh, ""
    say_step(len(mesh.faces), "decimating towards %d faces in halving stages (quadric)", faces)
    while len(current.faces) > faces:
        start = time.perf_counter()
        step = current.simplify_quadric_decimation(face_count=max(faces, len(current.faces) // 2))
        say_step(len(mesh.faces), "decimation stage %d -> %d faces (%.0f s)", len(current.faces), len(step.faces),
                 time.perf_counter() - start)
        ratio = abs(float(step.volume)) / volume if volume > 0 else float("nan")
        if not _closed(step):
            stop = f"the next stage ({len(step.faces)} faces) opened the surface"
        elif not abs(ratio - 1.0) <= DECIMATE_VOLUME_TOL:
            stop = f"the next stage ({len(step.faces)} faces) changed the volume x{ratio:.3f}"
        elif len(step.faces) > 0.9 * len(current.faces):
            stop = f"decimation stalled at {len(current.faces)} faces"
        if stop:
            break
        current = step
    if current is mesh:
        repairs.append(f"kept all {len(mesh.faces)} faces before remeshing: {stop} (GRT's quadric decimation "
                       "would have changed the object)")
        return mesh
    ratio = abs(float(current.volume)) / volume
    repairs.append(f"decimated {len(mesh.faces)} -> {len(current.faces)} faces (quadric, fast-simplification, halving "
                   f"stages, volume x{ratio:.4f})" + (f"; stopped early: {stop}, so the object is kept" if stop else ""))
    return current


def remesh(mesh: trimesh.Trimesh, edge: float, repairs: list[str], fix: str = "") -> trimesh.Trimesh:
    """Isotropic remeshing of a closed ``mesh`` to edge length ``edge`` (mesh units).

    A very fine input is decimated first (:func:`decimate`, towards twice the target's face count); a
    coarser input is first split flat to edges <= ``edge`` (the surface does not move) and its crease
    vertices are kept fixed, so that the remeshing keeps sharp edges and corners instead of cutting them.
    A result that is not closed and free of zero-area faces is remeshed again at a target edge 7% smaller,
    then 7% larger; if none is, the refusal says it is GRT's step that failed, and ``fix`` (a setting that
    avoids the step).
    """
    budget = target_faces(mesh, edge)
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    fixed = np.zeros(0, np.int32)
    if len(f) > 2 * FINE_FACTOR * budget:  # remeshing 300k faces directly takes ~10x longer
        small = decimate(mesh, 2 * budget, repairs)
        v, f = np.asarray(small.vertices, np.float64), np.asarray(small.faces, np.int64)
    elif len(f) < budget:
        v, f = trimesh.remesh.subdivide_to_size(v, f, max_edge=edge)
        fixed = crease_vertices(trimesh.Trimesh(v, f, process=False))
    left = []
    say_step(len(mesh.faces), "remeshing isotropically to ~%d faces (gpytoolbox, %d iterations)", budget,
             REMESH_ITERATIONS)
    for h in (edge, 0.93 * edge, 1.07 * edge):
        try:
            rv, rf = gpytoolbox.remesh_botsch(np.array(v, np.float64), np.array(f, np.int32), i=REMESH_ITERATIONS,
                                              h=h, feature=fixed, project=True)
        except ValueError as exc:  # gpytoolbox refuses a non-manifold input
            raise MeshError(f"GRT's isotropic remeshing step failed ({exc}); " + (fix or "set mesh.remesh=off")) from None
        out = fix_flat_faces(trimesh.Trimesh(np.array(rv, np.float64), np.array(rf, np.int64), process=False))
        flipped, flat = out.metadata.pop("grt_flat_faces_fixed"), out.metadata.pop("grt_flat_faces_left")
        out.metadata.pop("grt_flat_faces_moved")
        left = ([f"{flat} zero-area faces"] if flat else []) + ([] if _closed(out) else ["an open or non-manifold surface"])
        if not left:
            break
    else:
        raise MeshError(f"GRT's isotropic remeshing step (gpytoolbox remesh_botsch, target edge {edge:.4g} mesh units, "
                        f"and 7% finer and coarser) left {' and '.join(left)}: the fault is GRT's step, not the "
                        f"input. Fix: {fix or 'set mesh.remesh=off, or another mesh.edge_length'}")
    kept = f", {len(fixed)} crease vertices kept" if len(fixed) else ""
    flips = f"; {flipped} zero-area faces between kept crease vertices collapsed or flipped" if flipped else ""
    again = f"; target edge {h:.4g} after the first tries left zero-area faces or holes" if h != edge else ""
    repairs.append(f"remeshed isotropically: {len(mesh.faces)} -> {len(out.faces)} faces, target edge {edge:.4g} "
                   f"mesh units (gpytoolbox remesh_botsch, {REMESH_ITERATIONS} iterations{kept}{flips}{again})")
    return out


def fix_flat_faces(mesh: trimesh.Trimesh, max_flips: int | None = None) -> trimesh.Trimesh:
    """Collapse zero-area faces without opening the surface; returns the mesh (a new one when anything changed).

    A *needle* (two of its vertices at the same place, e.g. two crease vertices of a boolean union 1e-9
    apart) is collapsed: the coincident vertices are merged and the faces left with a repeated vertex
    dropped. A *cap* ``(a, b, c)`` with ``c`` on its longest edge ``ab`` (a T-junction closed by a flat
    face, as CAD exporters leave along seams) is flipped with its neighbour ``(b, a, d)`` into ``(c, a, d)``
    and ``(c, d, b)``: the same surface, orientation kept, nothing opened. A flip that would duplicate an
    edge is collapsed instead (``c`` merged into the nearer end of ``ab``). The count of all is in
    ``mesh.metadata["grt_flat_faces_fixed"]``, the faces still flat in ``["grt_flat_faces_left"]`` and the
    farthest a vertex moved (mesh units; 0 for flips) in ``["grt_flat_faces_moved"]``.
    """
    def flat(m):
        return np.flatnonzero(~m.nondegenerate_faces(height=1e-12))

    fixed = 0
    if len(flat(mesh)):
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        tol = 1e-7 * float(np.ptp(v, axis=0).max())
        _, first, inverse = np.unique(np.round(v / tol).astype(np.int64), axis=0, return_index=True,
                                      return_inverse=True)
        f = first[inverse.ravel()][f]
        keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])
        if not keep.all():
            fixed += int((~keep).sum())
            mesh = trimesh.Trimesh(v, f[keep], process=False)
            mesh.remove_unreferenced_vertices()
    faces = np.array(mesh.faces)
    vertices = np.asarray(mesh.vertices)
    bad = flat(trimesh.Trimesh(vertices, faces, process=False))
    limit = max_flips if max_flips is not None else 10 * len(bad) + 100
    skipped: set[int] = set()
    moved = 0.0
    for _ in range(limit):
        bad = [i for i in flat(trimesh.Trimesh(vertices, faces, process=False)) if i not in skipped]
        if not bad:
            break
        i = bad[0]
        tri = vertices[faces[i]]
        lengths = [np.linalg.norm(tri[(k + 1) % 3] - tri[k]) for k in range(3)]
        k = int(np.argmax(lengths))
        a, b, c = faces[i, k], faces[i, (k + 1) % 3], faces[i, (k + 2) % 3]
        if min(lengths) <= 1e-3 * max(lengths):  # a needle: merge its short edge (flipping it only moves it)
            s = int(np.argmin(lengths))
            p, q = faces[i, s], faces[i, (s + 1) % 3]
            collapsed = _collapse_onto_edge(vertices, faces, p, p, q)
            if collapsed is None:
                skipped.add(i)
            else:
                (faces, step), skipped = collapsed, set()
                fixed, moved = fixed + 1, max(moved, step)
            continue
        nb = np.flatnonzero(((faces == b) & (np.roll(faces, -1, axis=1) == a)).any(1))
        d = int(faces[nb[0]][~np.isin(faces[nb[0]], (a, b))][0]) if len(nb) == 1 else c
        if d == c or ((faces == c).any(1) & (faces == d).any(1)).any():  # no neighbour, or edge cd exists
            collapsed = _collapse_onto_edge(vertices, faces, a, b, c)
            if collapsed is None:
                skipped.add(i)
            else:
                (faces, step), skipped = collapsed, set()
                fixed, moved = fixed + 1, max(moved, step)
            continue
        faces[i], faces[nb[0]] = (c, a, d), (c, d, b)
        fixed += 1
    if fixed:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        mesh.remove_unreferenced_vertices()
    mesh.metadata["grt_flat_faces_fixed"] = fixed
    mesh.metadata["grt_flat_faces_moved"] = moved
    mesh.metadata["grt_flat_faces_left"] = len(flat(mesh))
    return mesh


def _collapse_onto_edge(vertices: np.ndarray, faces: np.ndarray, a: int, b: int,
                        c: int) -> tuple[np.ndarray, float] | None:
    """Faces with ``c`` (on the edge ``ab`` of a flat face) merged into the nearer of ``a``, ``b``; None when that
    would open the surface or duplicate a face; with the distance ``c`` moved (at most half the edge)."""
    near = a if np.linalg.norm(vertices[c] - vertices[a]) <= np.linalg.norm(vertices[c] - vertices[b]) else b
    new = np.where(faces == c, near, faces)
    new = new[(new[:, 0] != new[:, 1]) & (new[:, 1] != new[:, 2]) & (new[:, 2] != new[:, 0])]
    trial = trimesh.Trimesh(vertices, new, process=False)
    if not trial.is_watertight or not trial.unique_faces().all():
        return None
    return new, float(np.linalg.norm(vertices[c] - vertices[near]))


# ------------------------------------------------------------------------------------------ report
def describe(mesh: trimesh.Trimesh) -> list[str]:
    """Console lines of a loaded mesh's preparation: every repair, the remesh decision, the fidelity figures."""
    prep = mesh.metadata.get("grt_prepare")
    if not prep:
        return [f"repaired input: {r}" for r in mesh.metadata.get("grt_repairs", [])]
    lines = [f"mesh {prep['source']}: {prep['input']['faces']} -> {prep['output']['faces']} faces, "
             f"{prep['output']['vertices']} vertices; {prep['remesh']['decision']}"]
    lines += [f"  repaired: {r}" for r in prep["repairs"]]
    fid, tol = prep["fidelity"], prep["tolerance"]
    estimate = " (input volume estimated: the input is open)" if fid.get("volume_estimated") else ""
    lines.append(f"  fidelity: volume ratio {fid['volume_ratio']:.4f}{estimate}, Hausdorff {fid['hausdorff_mm']:.3f} mm, "
                 f"Chamfer {fid['chamfer_mm']:.3f} mm ({'exact, surface unchanged' if prep['exact'] else 'measured'};"
                 f" allowed: {tol['fidelity_mm']:g} mm, volume ±{tol['volume_tol']:.0%})")
    if prep["output"].get("self_intersections"):
        lines.append(f"  warning: the surface crosses itself in {prep['output']['self_intersections']} face pairs "
                     "(kept as given; a candidate is judged by the crossings it adds). Fix the input in a "
                     "modelling tool for a printable object")
    return lines


def settings_record(settings: MeshSettings) -> dict:
    return asdict(settings)
