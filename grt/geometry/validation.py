"""What makes a mesh usable by GRT (watertight, manifold, outward, one body), and the error when it is not.

The bottom of :mod:`grt.geometry`: the input pipeline (:mod:`grt.geometry.prepare`) and the loaders
(:mod:`grt.geometry.mesh`) both check meshes with :func:`mesh_problems` and refuse them with :class:`MeshError`.
"""

from __future__ import annotations

import manifold3d
import numpy as np
import trimesh

from grt.errors import UserError


class MeshError(UserError):
    """A mesh that cannot be used; the message says what is wrong and how to fix it."""


def mesh_problems(mesh: trimesh.Trimesh) -> list[str]:
    """Everything that keeps ``mesh`` from being used as it is (empty list: valid).

    Checks: finite vertices, no degenerate or duplicate faces, no unreferenced vertices, watertight
    (every edge shared by exactly two faces), manifold (manifold3d accepts it, which also rejects
    non-manifold vertices), consistent outward winding, one connected component.
    """
    problems = []
    if len(mesh.faces) == 0:
        return ["mesh has no faces"]
    if not np.all(np.isfinite(mesh.vertices)):
        problems.append(f"{int((~np.isfinite(mesh.vertices)).any(1).sum())} vertices are NaN/inf")
        return problems
    n_degenerate = int(len(mesh.faces) - mesh.nondegenerate_faces(height=1e-12).sum())
    if n_degenerate:
        problems.append(f"{n_degenerate} degenerate (zero-area) faces")
    n_dup = int(len(mesh.faces) - mesh.unique_faces().sum())
    if n_dup:
        problems.append(f"{n_dup} duplicate faces")
    referenced = np.zeros(len(mesh.vertices), bool)
    referenced[mesh.faces.ravel()] = True
    if not referenced.all():
        problems.append(f"{int((~referenced).sum())} unreferenced vertices")
    if not mesh.is_watertight:
        problems.append("not watertight (has holes or open boundary edges)")
    elif not manifold3d_accepts(mesh):
        problems.append("not manifold (manifold3d rejects it: non-manifold edges or vertices)")
    if mesh.is_watertight and not mesh.is_winding_consistent:
        problems.append("inconsistent face winding")
    elif mesh.is_watertight and mesh.volume < 0:
        problems.append("faces point inwards (negative volume)")
    n_comp = len(trimesh.graph.connected_components(mesh.face_adjacency, nodes=np.arange(len(mesh.faces)),
                                                    min_len=1))
    if n_comp > 1:
        problems.append(f"{n_comp} connected components")
    return problems


def manifold3d_accepts(mesh: trimesh.Trimesh) -> bool:
    """Whether manifold3d accepts ``mesh`` as a closed manifold solid."""
    m = manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(mesh.vertices, np.float32),
                                            tri_verts=np.asarray(mesh.faces, np.uint32)))
    return m.status() == manifold3d.Error.NoError and m.num_tri() > 0
