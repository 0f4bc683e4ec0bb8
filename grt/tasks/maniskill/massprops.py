"""A swapped actor's mass, centre of mass and inertia: the candidate's solid with the stock actor's densities.

PhysX gives a body the mass properties of its collision shapes, each shape with its density: for the stock
actor, its primitives (a box, a sphere); for a candidate, its convex parts. Two things then go wrong when the
parts are not the primitives:

- **Parts that straddle records.** CoACD cuts PullCubeTool's L (a handle of density 500 and a hook of 1000
  kg/m^3) where it likes, so a part that is half handle takes one density: the mass came out right by chance
  (1.0001) while the centre of mass moved 1.6 mm and an inertia grew 11%.
- **Parts inside the surface.** A 64-vertex hull of a sphere is 10% lighter than the sphere.

So the body's mass properties are set explicitly from the candidate's *mesh* (its watertight solid, not its
collision parts) under the **density field of the stock records**: inside stock record ``r``'s solid the
candidate weighs that record's density (a point inside two records counts twice, as PhysX counts the overlap
of the stock boxes); outside every record (a bump) it weighs the density of the nearest record. A round
record's density is scaled by its primitive's exact volume over its solid's (an icosphere is 1% smaller than
its sphere), so the stock actor's own geometry comes out with the stock body's mass, centre of mass and
inertia, and a candidate's change with its shape, continuously. An env that sets the mass itself
(``set_mass_and_inertia``) keeps its numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import manifold3d as m3
import numpy as np
import trimesh


@dataclass(frozen=True)
class MassProperties:
    """Attributes: mass (kg); com ``(3,)`` (m); inertia ``(3, 3)`` about the centre of mass (kg m^2), actor frame."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray

    def principal(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(com (3,), wxyz quaternion of the principal axes (4,), principal moments (3,))``, PhysX's form."""
        moments, axes = np.linalg.eigh(0.5 * (self.inertia + self.inertia.T))
        if np.linalg.det(axes) < 0:
            axes[:, 2] *= -1
        return self.com.copy(), _matrix_quat(axes), np.maximum(moments, 0.0)


def _matrix_quat(r: np.ndarray) -> np.ndarray:
    """wxyz quaternion of a ``(3, 3)`` rotation."""
    t = np.eye(4)
    t[:3, :3] = r
    return np.asarray(trimesh.transformations.quaternion_from_matrix(t), np.float64)


def _manifold(mesh: trimesh.Trimesh) -> m3.Manifold:
    solid = m3.Manifold(m3.Mesh(vert_properties=np.asarray(mesh.vertices, np.float32),
                                tri_verts=np.asarray(mesh.faces, np.uint32)))
    if solid.status() != m3.Error.NoError:
        raise ValueError(f"not a closed manifold solid ({solid.status()})")
    return solid


def _trimesh(solid: m3.Manifold) -> trimesh.Trimesh:
    out = solid.to_mesh()
    return trimesh.Trimesh(np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts), process=False)


def of_solid(mesh: trimesh.Trimesh, density: float) -> MassProperties:
    """The mass properties of a closed mesh (m) of uniform ``density`` (kg/m^3)."""
    if len(mesh.faces) < 4:
        return MassProperties(0.0, np.zeros(3), np.zeros((3, 3)))
    with np.errstate(divide="ignore", invalid="ignore"):  # a sliver of zero volume: skipped just below
        props = trimesh.triangles.mass_properties(mesh.triangles, density=1.0, skip_inertia=False)
    if abs(float(props["volume"])) < 1e-15:
        return MassProperties(0.0, np.zeros(3), np.zeros((3, 3)))
    return MassProperties(float(props["volume"]) * density, np.asarray(props["center_mass"], np.float64),
                          np.asarray(props["inertia"], np.float64) * density)


def combine(items: list[MassProperties]) -> MassProperties:
    """One body of several (parallel-axis theorem)."""
    mass = float(sum(p.mass for p in items))
    if mass <= 0:
        return MassProperties(0.0, np.zeros(3), np.zeros((3, 3)))
    com = sum(p.mass * p.com for p in items) / mass
    inertia = np.zeros((3, 3))
    for p in items:
        d = p.com - com
        inertia += p.inertia + p.mass * (d @ d * np.eye(3) - np.outer(d, d))
    return MassProperties(mass, com, inertia)


def candidate_mass(mesh: trimesh.Trimesh, solids: list[trimesh.Trimesh], densities: list[float]) -> MassProperties:
    """The mass properties of ``mesh`` (actor frame, m) under the records' density field (see the module docstring).

    Args:
        mesh: the candidate's closed mesh; solids: the stock records' solids (actor frame, scaled as the
            candidate is); densities: each record's density (kg/m^3, already scaled to its primitive's volume).

    Raises:
        ValueError: the mesh or a solid is not a closed manifold.
    """
    body = _manifold(mesh)
    records = [_manifold(s) for s in solids]
    items = [of_solid(_trimesh(body ^ r), rho) for r, rho in zip(records, densities, strict=True)]
    outside = body - m3.Manifold.batch_boolean(records, m3.OpType.Add) if len(records) > 1 else body - records[0]
    rest = _trimesh(outside)
    if len(rest.faces):
        for piece in rest.split(only_watertight=False) or [rest]:
            centre = piece.centroid
            gaps = [float(np.linalg.norm(np.clip(centre, *s.bounds) - centre)) for s in solids]
            items.append(of_solid(piece, densities[int(np.argmin(gaps))]))
    return combine(items)
