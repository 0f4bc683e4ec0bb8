"""Loading, validation and repair of bad meshes: documented repair or a clear error."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grt.geometry.mesh import MeshError, load_mesh, prepare_mesh
from grt.objects import UnknownObjectError


def test_open_mesh_is_repaired_and_recorded():
    m = trimesh.creation.icosphere(2)
    m.update_faces(np.arange(1, len(m.faces)))  # punch a hole
    fixed = prepare_mesh(m)
    assert fixed.is_watertight and fixed.metadata["grt_repairs"]
    with pytest.raises(MeshError, match="not watertight"):
        prepare_mesh(m, repair=False)


def test_inverted_mesh_is_flipped():
    m = trimesh.creation.icosphere(2)
    m.invert()
    fixed = prepare_mesh(m)
    assert fixed.volume > 0 and any("inward" in r for r in fixed.metadata["grt_repairs"])


def test_nan_vertices_rejected():
    m = trimesh.creation.icosphere(1)
    v = m.vertices.copy()
    v[0] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        prepare_mesh(trimesh.Trimesh(v, m.faces, process=False))


def test_empty_and_corrupt_files(tmp_path):
    empty = tmp_path / "empty.obj"
    empty.write_text("")
    with pytest.raises(MeshError, match="empty"):
        load_mesh(empty)
    corrupt = tmp_path / "corrupt.stl"
    corrupt.write_bytes(b"solid x\n facet normal garbage\n\x00\x01\x02")
    with pytest.raises(MeshError, match="corrupt|no triangles|could not be read"):
        load_mesh(corrupt)


def test_unknown_object_name_lists_known_and_mentions_paths():
    with pytest.raises(UnknownObjectError, match="mug") as err:
        load_mesh("teapot")
    assert "teapot" in str(err.value) and "path" in str(err.value)
    assert isinstance(err.value, ValueError)
