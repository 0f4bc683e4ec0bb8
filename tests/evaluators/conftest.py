"""Fixtures of the evaluation tests: a small concave solid, its deformation, toy task sessions."""

from __future__ import annotations

from pathlib import Path

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from grt.geometry.deform import ShapeDeformer

HERE = Path(__file__).parent


def u_shape() -> trimesh.Trimesh:
    """A 6 x 3 x 5 cm U-shaped block (a slot cut from the top), resting on z = 0, ~1.2k faces."""
    outer = m3.Manifold.cube([0.06, 0.03, 0.05])
    slot = m3.Manifold.cube([0.03, 0.04, 0.04]).translate([0.015, -0.005, 0.012])
    solid = (outer - slot).translate([-0.03, -0.015, 0.0]).refine_to_length(0.006).to_mesh()
    return trimesh.Trimesh(np.asarray(solid.vert_properties)[:, :3], np.asarray(solid.tri_verts), process=False)


@pytest.fixture(scope="session")
def u_mesh() -> trimesh.Trimesh:
    return u_shape()


@pytest.fixture(scope="session")
def u_deformed(u_mesh) -> trimesh.Trimesh:
    """The U-shape with its two top corners pulled apart (~3 mm), same faces."""
    v = u_mesh.vertices
    anchors = np.flatnonzero(v[:, 2] < 1e-6)
    top = np.flatnonzero(v[:, 2] > 0.05 - 1e-6)
    handles = top[np.argsort(v[top, 0])[[0, -1]]]
    deformer = ShapeDeformer(u_mesh, handles, anchors)
    return deformer.meshes(np.array([[[-0.05, 0.0, 0.03], [0.05, 0.02, 0.0]]]))[0]


@pytest.fixture(scope="session")
def toy_configs():
    """``(task, policy)`` dicts building :class:`_toy_session.ToySession` in worker processes."""

    def make(**session_kwargs):
        task = {"name": "toy", "session": {"_target_": "_toy_session.ToySession", **session_kwargs}}
        policy = {"_target_": "_toy_session.ToyPolicy", "fill": 0.5}
        return task, policy

    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(HERE))  # spawned workers inherit sys.path
        yield make
