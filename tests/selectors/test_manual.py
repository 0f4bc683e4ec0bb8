"""HandleSet and the manual selector: indices, boxes, spheres, named regions, JSON files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from grt.selectors.base import HandleSet
from grt.selectors.manual import ManualSelector


def test_handleset_json_round_trip(tmp_path):
    hs = HandleSet([3, 1], [7, 8, 9], {"why": "test"})
    again = HandleSet.from_json(hs.to_json())
    np.testing.assert_array_equal(again.handles, [3, 1])
    np.testing.assert_array_equal(again.anchors, [7, 8, 9])
    assert again.notes == {"why": "test"}
    (tmp_path / "h.json").write_text(hs.to_json())
    assert HandleSet.from_json(tmp_path / "h.json").handles.tolist() == [3, 1]


def test_handleset_rejects_overlap_and_empty():
    with pytest.raises(ValueError, match="overlap"):
        HandleSet([1, 2], [2, 3, 4])
    with pytest.raises(ValueError, match="at least one handle"):
        HandleSet([], [2, 3, 4])
    with pytest.raises(ValueError, match="out of range"):
        HandleSet([1], [2, 3, 99]).check(50)


def test_box_and_sphere_regions_select_the_right_vertices(sphere):
    v = sphere.vertices
    box = [[0.02, -0.05, -0.05], [0.05, 0.05, 0.05]]
    ball = {"center": [-0.04, 0.0, 0.0], "radius": 0.015}
    hs = ManualSelector(handle_regions=[{"box": box}], anchor_regions=[{"sphere": ball}]).select(sphere, "t")
    np.testing.assert_array_equal(hs.handles, np.flatnonzero(v[:, 0] >= 0.02))
    expected = np.flatnonzero(np.linalg.norm(v - [-0.04, 0, 0], axis=1) <= 0.015)
    np.testing.assert_array_equal(hs.anchors, expected)
    assert len(expected) >= 3


def test_indices_far_anchors_and_no_mutation(sphere):
    before = sphere.vertices.copy()
    hs = ManualSelector(handles=[0, 5], far_anchors=4).select(sphere, "t")
    assert hs.handles.tolist() == [0, 5] and len(hs.anchors) == 4
    # the far anchors are on the other side of the sphere from the handles
    d = np.linalg.norm(sphere.vertices[hs.anchors][:, None] - sphere.vertices[hs.handles][None], axis=-1)
    assert d.min() > 0.04
    np.testing.assert_array_equal(sphere.vertices, before)


def test_json_file_and_errors(sphere, tmp_path):
    path = tmp_path / "sel.json"
    top = np.flatnonzero(sphere.vertices[:, 2] > 0.03)[:2].tolist()
    path.write_text(json.dumps({"handles": [top[0]], "anchor_regions": [{"box": [[-1, -1, -1], [1, 1, -0.03]]}]}))
    hs = ManualSelector(handles=[top[1]], file=str(path)).select(sphere, "t")
    assert hs.handles.tolist() == sorted(top)
    assert np.all(sphere.vertices[hs.anchors][:, 2] <= -0.03)
    with pytest.raises(ValueError, match="overlap"):
        ManualSelector(handles=[1], anchors=[1, 2, 3]).select(sphere, "t")
    with pytest.raises(ValueError, match="needs handles"):
        ManualSelector().select(sphere, "t")
    with pytest.raises(ValueError, match="no vertex"):
        ManualSelector(handle_regions=[{"box": [[1, 1, 1], [2, 2, 2]]}]).select(sphere, "t")


def test_named_region_of_a_builtin_object():
    objects = pytest.importorskip("grt.objects")
    mesh = objects.get_object("mug")
    lo, hi = np.asarray(objects.object_regions("mug")["handle"], float).reshape(2, 3)
    hs = ManualSelector(handle_regions=["mug:handle"], max_per_region=6).select(mesh, "t")
    assert len(hs.handles) == 6
    inside = np.all((mesh.vertices[hs.handles] >= lo) & (mesh.vertices[hs.handles] <= hi), axis=1)
    assert inside.all()
    with pytest.raises(ValueError, match="no region"):
        ManualSelector(handle_regions=["mug:spout"]).select(mesh, "t")


@pytest.mark.parametrize("bad", [[1.5], [[1, 2]], ["abc"], [-1], [True]])
def test_an_entry_that_is_no_vertex_index_is_refused_where_it_is_given(bad, tmp_path):
    """1.5 was truncated to vertex 1 without a word; [1, 2] and 'abc' failed deep in numpy (a traceback)."""
    from grt.selectors.base import SelectorError

    with pytest.raises(SelectorError, match=r"selector\.handles: .* is not a vertex index; give integers >= 0"):
        ManualSelector(handles=bad)
    path = tmp_path / "sel.json"
    path.write_text(json.dumps({"anchors": bad}))
    with pytest.raises(SelectorError, match=rf"selector\.anchors \(with selector\.file={path}\): .* is not a vertex"):
        ManualSelector(handles=[0], file=str(path))
    assert ManualSelector(handles=np.array([3, 4])).spec["handles"] == [3, 4]  # numpy's integers are indices
