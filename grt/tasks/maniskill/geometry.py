"""A ManiSkill actor's geometry, in its own frame and in GRT's.

**The actor frame** is the frame the env builds and poses the actor in (ManiSkill's cube: centred on its
origin; the charger: its origin where the pins meet the base). **GRT's frame** is the one every GRT mesh
lives in: meters, z up, resting on z = 0, centred in x/y (``docs/interfaces.md``, Objects). The two
differ by one translation per task, taken from the *stock* actor's collision geometry::

    offset = (centre x, centre y, lowest z) of the stock actor's bounding box, in the actor frame
    p_actor = p_grt + offset          p_grt = p_actor - offset

so the nominal object sits in GRT's frame exactly as GRT's own objects do, and a candidate deformed in
GRT's frame goes back into the actor frame by the same constant (vertex for vertex, no re-centring: a
bump on the bottom of a candidate stays a bump, it does not move the actor's origin). A user's mesh given
instead of the actor's geometry is read in GRT's frame and placed the same way (its footprint centre and
bottom where the stock actor's are); a mesh whose bounding box sits off GRT's frame by more than a
quarter of its size (one given in the actor frame, centred on its origin) is refused by
:func:`check_grt_frame`.

**The nominal object** (:func:`records_mesh`) is the stock actor's collision records made one watertight
mesh in the actor frame: boxes, spheres, capsules and cylinders (ManiSkill's capsules and cylinders lie
along x), convex mesh files (their hulls, as PhysX uses them), triangle-mesh files, several records of
one actor united (PlugCharger's charger: three boxes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from grt.tasks.base import TaskInputError

#: subdivisions of the icospheres and segments of the round primitives: fine enough that a remeshed sphere
#: keeps its volume within 0.5%, coarse enough to stay small (642 vertices).
SPHERE_SUBDIVISIONS = 3
ROUND_SECTIONS = 48
#: a mesh whose bounding box is off GRT's frame by more than this fraction of its size is in another frame.
FRAME_TOLERANCE = 0.25


class ActorGeometryError(TaskInputError):
    """An actor whose collision geometry GRT cannot turn into a mesh (a plane, an unreadable file)."""


class FrameError(TaskInputError):
    """A mesh that is not in GRT's frame (resting on z = 0, centred in x/y): one line with the shift."""


@dataclass
class ShapeRecord:
    """One collision record of a stock actor, as the env's builder holds it (poses in the actor frame).

    Attributes:
        kind: ``box`` | ``sphere`` | ``capsule`` | ``cylinder`` | ``convex_mesh`` | ``nonconvex_mesh`` |
            ``multiple_convex_meshes`` | ``plane``.
        pose: ``(4, 4)`` the record's pose in the actor frame.
        mesh: the record's solid in the actor frame (m), ``None`` for a plane.
        density: kg/m^3; material: the ``PhysxMaterial``; patch radii: PhysX's.
        volume: the primitive's own volume (m^3; the solid of a sphere, a capsule or a cylinder is a polyhedron
            about 1% smaller), 0 for a plane.
    """

    kind: str
    pose: np.ndarray
    mesh: trimesh.Trimesh | None
    density: float
    material: object = None
    patch_radius: float = 0.0
    min_patch_radius: float = 0.0
    volume: float = 0.0


def _pose_matrix(pose) -> np.ndarray:
    return np.asarray(pose.to_transformation_matrix(), np.float64)


def _along_x(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """trimesh builds capsules and cylinders along z; ManiSkill's lie along x."""
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    return mesh


def record_solid(record) -> trimesh.Trimesh | None:
    """The solid of one SAPIEN ``CollisionShapeRecord`` in the actor frame (m); ``None`` for a plane.

    Raises:
        ActorGeometryError: a mesh file that cannot be read.
    """
    kind = record.type
    if kind == "plane":
        return None
    if kind == "box":
        solid = trimesh.creation.box(extents=2 * np.asarray(record.scale, np.float64))
    elif kind == "sphere":
        solid = trimesh.creation.icosphere(SPHERE_SUBDIVISIONS, radius=float(record.radius))
    elif kind == "capsule":
        solid = _along_x(trimesh.creation.capsule(2 * float(record.length), float(record.radius),
                                                  count=[ROUND_SECTIONS, ROUND_SECTIONS]))
    elif kind == "cylinder":
        solid = _along_x(trimesh.creation.cylinder(float(record.radius), 2 * float(record.length),
                                                   sections=ROUND_SECTIONS))
    elif kind in ("convex_mesh", "nonconvex_mesh", "multiple_convex_meshes"):
        try:
            loaded = trimesh.load(record.filename, force="mesh", process=True)
        except Exception as err:  # noqa: BLE001 - any unreadable file is the same problem
            raise ActorGeometryError(f"the actor's collision mesh {record.filename} cannot be read "
                                     f"({type(err).__name__}: {err}); give object=MESH (meters, GRT's frame)") from None
        loaded.apply_scale(np.asarray(record.scale, np.float64))
        solid = loaded.convex_hull if kind == "convex_mesh" else loaded
        if kind == "multiple_convex_meshes":  # PhysX uses each body's hull
            bodies = loaded.split(only_watertight=False) or [loaded]
            solid = trimesh.util.concatenate([b.convex_hull for b in bodies])
    else:
        raise ActorGeometryError(f"the actor has a collision record of type {kind!r}, which GRT cannot read; "
                                 "give object=MESH (meters, GRT's frame)")
    solid.apply_transform(_pose_matrix(record.pose))
    return solid


def record_volume(record, solid: trimesh.Trimesh | None) -> float:
    """The volume (m^3) PhysX gives a SAPIEN collision record: the primitive's own for a sphere, a capsule or a
    cylinder (``length`` is the half length), the solid's for a box or a mesh, 0 for a plane."""
    radius, half = float(getattr(record, "radius", 0.0)), float(getattr(record, "length", 0.0))
    exact = {"sphere": 4.0 / 3.0 * np.pi * radius ** 3,
             "capsule": np.pi * radius ** 2 * 2 * half + 4.0 / 3.0 * np.pi * radius ** 3,
             "cylinder": np.pi * radius ** 2 * 2 * half}
    if record.type in exact:
        return float(exact[record.type])
    return abs(float(solid.volume)) if solid is not None else 0.0


def read_records(builder) -> list[ShapeRecord]:
    """The collision records of a ManiSkill ``ActorBuilder`` (before it builds), each with its solid."""
    out = []
    for r in builder.collision_records:
        solid = record_solid(r)
        out.append(ShapeRecord(r.type, _pose_matrix(r.pose), solid, float(r.density), r.material,
                               float(r.patch_radius), float(r.min_patch_radius), record_volume(r, solid)))
    return out


def records_mesh(records: list[ShapeRecord]) -> trimesh.Trimesh:
    """The records' solids as one watertight mesh in the actor frame (several solids united).

    Raises:
        ActorGeometryError: no solid (no collision record, or planes only), or solids that do not unite.
    """
    solids = [r.mesh for r in records if r.mesh is not None]
    if not solids:
        raise ActorGeometryError("the actor has no collision geometry GRT can read (no record, or a plane); "
                                 "give object=MESH (meters, GRT's frame)")
    if len(solids) == 1:
        mesh = solids[0].copy()
    else:
        try:
            mesh = trimesh.boolean.union(solids, engine="manifold")
        except Exception as err:  # noqa: BLE001 - manifold3d's errors vary
            raise ActorGeometryError(f"the actor's {len(solids)} collision shapes do not unite into one solid "
                                     f"({err}); give object=MESH (meters, GRT's frame)") from None
    mesh.merge_vertices()
    if not mesh.is_watertight:
        mesh = mesh.convex_hull if len(solids) == 1 else mesh
    if mesh.volume < 0:
        mesh.invert()
    return mesh


@dataclass
class ActorFrame:
    """The translation between GRT's frame and the actor frame (see the module docstring).

    Attributes:
        offset: ``(3,)`` m: ``p_actor = p_grt + offset``.
    """

    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def of(cls, actor_mesh: trimesh.Trimesh) -> ActorFrame:
        """The frame of a stock actor's geometry: its bounding box's footprint centre and bottom."""
        lo, hi = np.asarray(actor_mesh.bounds, np.float64)
        return cls(np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]))

    def to_actor(self, points: np.ndarray) -> np.ndarray:
        """GRT-frame points ``(..., 3)`` -> actor-frame points (m)."""
        return np.asarray(points, np.float64) + self.offset

    def to_grt(self, points: np.ndarray) -> np.ndarray:
        """Actor-frame points ``(..., 3)`` -> GRT-frame points (m)."""
        return np.asarray(points, np.float64) - self.offset

    def mesh_to_grt(self, mesh: trimesh.Trimesh) -> trimesh.Trimesh:
        out = mesh.copy()
        out.vertices = self.to_grt(out.vertices)
        return out


def check_grt_frame(mesh: trimesh.Trimesh, what: str = "the object") -> None:
    """Refuse a mesh whose bounding box is not where GRT's frame puts it (bottom on z = 0, centred in x/y),
    off by more than :data:`FRAME_TOLERANCE` of its size: a mesh in an actor's own frame (centred on its
    origin) would start inside the table and be flown out of it. A deformed candidate (a few mm off) passes.

    Raises:
        FrameError: one line giving the shift that puts the mesh in GRT's frame.
    """
    lo, hi = np.asarray(mesh.bounds, np.float64)
    size = np.maximum(hi - lo, 1e-9)
    centre = (lo + hi) / 2
    off = np.array([centre[0] / size[0], centre[1] / size[1], lo[2] / size[2]])
    if np.all(np.abs(off) <= FRAME_TOLERANCE):
        return
    shift = -np.array([centre[0], centre[1], lo[2]]) * 1000 + 0.0  # + 0.0: no '-0.0' in the message
    raise FrameError(f"{what} is not in GRT's frame: its lowest point is at z = {lo[2] * 1000:.1f} mm and its x/y centre "
                     f"at ({centre[0] * 1000:.1f}, {centre[1] * 1000:.1f}) mm, but GRT meshes rest on z = 0, centred in "
                     f"x/y (a mesh centred on its origin is in the actor's own frame): move it by "
                     f"({shift[0]:.1f}, {shift[1]:.1f}, {shift[2]:.1f}) mm (trimesh: mesh.apply_translation("
                     f"[{shift[0] / 1000:.4f}, {shift[1] / 1000:.4f}, {shift[2] / 1000:.4f}])) and export it again")


def nearest_records(parts: list[np.ndarray], records: list[ShapeRecord]) -> list[int]:
    """For each convex part ``(K, 3)`` (actor frame), the index of the stock record nearest its centroid
    (so each part takes that record's density and material: PullCubeTool's parts differ in density)."""
    solid = [i for i, r in enumerate(records) if r.mesh is not None]
    if len(solid) == 1:
        return [solid[0]] * len(parts)
    out = []
    for part in parts:
        c = np.asarray(part, np.float64).mean(axis=0)
        dist = [float(np.linalg.norm(np.clip(c, *records[i].mesh.bounds) - c)) for i in solid]
        out.append(solid[int(np.argmin(dist))])
    return out


#: the stock record kinds whose actor GRT builds with surface wedges (a round actor: one sphere, capsule or cylinder)
ROUND_KINDS = ("sphere", "capsule", "cylinder")
#: how many wedges cover a round actor's surface (measured on PlaceSphere-v1 and RollBall-v1:
#: experiments/maniskill/fidelity/README.md)
ROUND_WEDGES = 8


def is_round(records: list[ShapeRecord]) -> bool:
    """Whether the stock actor is one round primitive (a sphere, capsule or cylinder record and nothing else)."""
    solid = [r for r in records if r.mesh is not None]
    return len(solid) == 1 and solid[0].kind in ROUND_KINDS


def _directions(count: int) -> np.ndarray:
    """``(count, 3)`` unit directions spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * i / count)
    azimuth = np.pi * (1 + 5 ** 0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)


def _capped(points: np.ndarray, cap: int) -> np.ndarray:
    """The convex hull's vertices of ``points``, at most ``cap`` of them (farthest-point sampling beyond it)."""
    from scipy.spatial import ConvexHull

    verts = points[ConvexHull(points).vertices]
    if len(verts) <= cap:
        return verts
    chosen = [int(np.argmax(np.linalg.norm(verts - verts.mean(axis=0), axis=1)))]
    gap = np.linalg.norm(verts - verts[chosen[0]], axis=1)
    while len(chosen) < cap:
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, np.linalg.norm(verts - verts[chosen[-1]], axis=1))
    return verts[chosen]


def round_wedges(vertices: np.ndarray, cap: int, count: int = ROUND_WEDGES) -> list[np.ndarray]:
    """Convex caps that cover a round solid's surface finely: the mesh's vertices grouped by their direction
    from the centroid (``count`` evenly spread directions, each group widened to overlap its neighbours), each
    group's hull, at most ``cap`` vertices each; the actor's own parts fill the inside. One hull of ``cap``
    vertices is a coarse polyhedron (64 on a sphere: 10% of its volume missing, flat faces it rests and rolls
    on); ``count`` caps carry up to ``count`` times as many surface vertices.

    Args:
        vertices: ``(V, 3)`` the candidate mesh's vertices (actor frame, m); cap: vertices per wedge (>= 8).

    Returns:
        ``count`` arrays ``(K, 3)``, ``K <= cap`` (fewer when a group has too few vertices to span a wedge).
    """
    pts = np.asarray(vertices, np.float64)
    centre = pts.mean(axis=0)
    rays = pts - centre
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    score = rays @ _directions(count).T  # (V, count)
    best = score.max(axis=1, keepdims=True)
    wedges = []
    for k in range(count):
        group = pts[score[:, k] >= best[:, 0] - 0.05]
        if len(group) >= 4:
            wedges.append(_capped(group, max(8, int(cap))))
    return wedges
