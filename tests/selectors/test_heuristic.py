"""Heuristic and all-candidates selectors, and the anchors rule."""

from __future__ import annotations

import numpy as np

from grt.selectors.all import AllSelector
from grt.selectors.heuristic import HeuristicSelector
from grt.selectors.keypoints import sample_keypoints


def test_heuristic_draws_k_candidates(box):
    pool = sample_keypoints(box, seed=1).vertices
    hs = HeuristicSelector(k=5, seed=1).select(box, "grasp")
    assert len(hs.handles) == 5 and set(hs.handles) <= set(pool)
    # anchors: the candidates not chosen, nothing else (no protected regions, no extras)
    assert set(hs.anchors) == set(pool) - set(hs.handles)
    again = HeuristicSelector(k=5, seed=1).select(box, "grasp")
    np.testing.assert_array_equal(hs.handles, again.handles)
    other = HeuristicSelector(k=5, seed=2).select(box, "grasp")
    assert not np.array_equal(hs.handles, other.handles)


def test_all_selector_uses_every_candidate(box):
    pool = sample_keypoints(box, seed=0).vertices
    hs = AllSelector(far_anchors=6).select(box, "grasp")
    assert sorted(hs.handles) == sorted(pool)
    assert len(hs.anchors) == 6 and not set(hs.anchors) & set(hs.handles)


def test_protected_region_and_far_anchors(box):
    top = {"box": [[-1, -1, 0.014], [1, 1, 1]]}  # the box's top face (z = +1.5 cm)
    hs = HeuristicSelector(k=25, protected=[top], far_anchors=3).select(box, "insert")
    protected = np.flatnonzero(box.vertices[:, 2] >= 0.014)
    assert not set(hs.handles) & set(protected)
    assert set(protected) <= set(hs.anchors)
    assert hs.notes["protected_vertices"] == len(protected)


def test_min_anchors_when_every_candidate_is_a_handle(sphere):
    hs = AllSelector(far_anchors=0, min_anchors=3).select(sphere, "grasp")
    assert len(hs.anchors) == 3
