"""Collision geometry: CoACD cache by content, transported decomposition fidelity, hull limits."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grt.evaluators.collision import (
    CoacdCollision,
    CollisionError,
    TransportedCollision,
    hull_vertices,
    make_collision,
    validate_parts,
    volume_iou,
)


@pytest.fixture(scope="module")
def coacd_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("coacd")


@pytest.fixture(scope="module")
def fast(u_mesh, coacd_dir) -> TransportedCollision:
    return make_collision("fast", u_mesh, cache_dir=coacd_dir)


def test_cache_hit_by_content_not_path(u_mesh, coacd_dir, tmp_path):
    maker = CoacdCollision(cache_dir=coacd_dir)
    first = maker.parts(u_mesh)  # computed here or by the `fast` fixture: both leave the entry
    # The same content from a file under another name: a cache hit, identical parts.
    path = tmp_path / "renamed_object.ply"
    u_mesh.export(path)
    same = trimesh.load(path, process=False)
    same.metadata["grt_source"] = str(path)
    hits = maker.hits
    again = maker.parts(same)
    assert maker.hits == hits + 1
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    # One vertex moved by 0.1 mm: other content, other key.
    moved = u_mesh.copy()
    moved.vertices[0] += 1e-4
    assert maker.cache_path(moved) != maker.cache_path(u_mesh)
    # Other CoACD settings: other key.
    other = make_collision("coacd", coacd={"threshold": 0.08}, cache_dir=coacd_dir)
    assert other.cache_path(u_mesh) != maker.cache_path(u_mesh)


def test_cache_miss_computes_and_stores(u_mesh, tmp_path):
    maker = CoacdCollision(cache_dir=tmp_path)
    parts = maker.parts(u_mesh)
    assert (maker.misses, maker.hits) == (1, 0)
    assert maker.cache_path(u_mesh).is_file()
    assert len(parts) >= 2  # a U needs more than one hull
    assert all(len(p) <= 64 for p in parts)
    assert volume_iou(parts, u_mesh) > 0.97


def test_fast_path_follows_the_deformation(fast, u_mesh, u_deformed):
    parts = fast.parts(u_deformed)
    assert fast.fallbacks == 0
    assert all(len(p) <= 64 for p in parts)
    iou_deformed = volume_iou(parts, u_deformed)
    assert iou_deformed >= 0.95
    # The transported parts fit the deformed solid better than the nominal parts do.
    assert iou_deformed > volume_iou(fast.nominal_parts, u_deformed) + 0.01


@pytest.mark.slow
def test_fast_path_matches_fresh_coacd(fast, u_deformed):
    fresh = CoacdCollision(cache_dir=False).parts(u_deformed)
    assert volume_iou(fast.parts(u_deformed), fresh) >= 0.95


def test_fast_path_falls_back_when_faces_differ(fast, coacd_dir):
    box = trimesh.creation.box([0.02, 0.03, 0.04])
    parts = fast.parts(box)
    assert fast.fallbacks == 1
    assert volume_iou(parts, box) > 0.99


def test_hull_vertex_cap_keeps_the_volume():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(2000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)
    capped = hull_vertices(pts, 64)
    assert len(capped) == 64
    # A sphere is the worst case: the best 64-vertex inscribed polytope keeps ~93% of the volume.
    assert volume_iou([capped], [pts]) > 0.88
    assert volume_iou([hull_vertices(pts, 64, batch=1)], [pts]) > 0.9


def test_degenerate_parts_name_the_mesh():
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    with pytest.raises(CollisionError, match="my_mug.obj.*part 1 is degenerate"):
        validate_parts([np.eye(3, 3).tolist() + [[1, 1, 1]], flat], "my_mug.obj")
    with pytest.raises(CollisionError, match="no parts"):
        validate_parts([], "my_mug.obj")
    with pytest.raises(CollisionError, match="shape"):
        validate_parts([np.zeros((2, 3))], "my_mug.obj")


def test_unknown_kind_and_missing_nominal():
    with pytest.raises(ValueError, match="unknown collision kind"):
        make_collision("vhacd")
    with pytest.raises(ValueError, match="nominal"):
        make_collision("fast")
