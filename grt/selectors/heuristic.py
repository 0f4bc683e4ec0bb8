"""Heuristic handle selection: handles drawn uniformly from the keypoint sampler's candidates.

The paper's "Heuristic" ablation (lines 402-408): every method starts from the candidate pool of the
fixed geometric heuristic (:mod:`grt.selectors.keypoints`); the heuristic variant draws ``k`` of them
uniformly at random, with ``k`` matched to the VLM's mean handle count.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

from grt.selectors.base import HandleSelector, HandleSet, choose_anchors
from grt.selectors.keypoints import Keypoints, sample_keypoints
from grt.selectors.regions import RegionSpec, region_vertices


class KeypointSelector(HandleSelector):
    """Shared part of the selectors that choose among the heuristic keypoints.

    Anchors (see :func:`grt.selectors.base.choose_anchors`): candidate keypoints not chosen as
    handles, plus every vertex in a ``protected`` region, plus ``far_anchors`` vertices far from the
    handles; never a handle, at least ``min_anchors`` (>= 3). Keypoints inside a protected region
    are never handles.

    Args:
        num_keypoints: ``N`` candidates of the sampler (paper: 25).
        delta: sampler separation, unit-cube units (paper: 0.1).
        num_samples: surface samples of the sampler (paper: 20,000).
        protected: region specs the task keeps fixed (:mod:`grt.selectors.regions`, meters).
        far_anchors: extra anchors far from the handles.
        min_anchors: the fewest anchors.
        seed: seeds the sampler and any random draw.
    """

    name = "keypoints"

    def __init__(self, num_keypoints: int = 25, delta: float = 0.1, num_samples: int = 20_000,
                 protected: Sequence[RegionSpec] = (), far_anchors: int = 0, min_anchors: int = 3,
                 seed: int = 0):
        self.num_keypoints, self.delta, self.num_samples = int(num_keypoints), float(delta), int(num_samples)
        self.protected = list(protected)
        self.far_anchors, self.min_anchors, self.seed = int(far_anchors), int(min_anchors), int(seed)

    def keypoints(self, mesh: trimesh.Trimesh) -> Keypoints:
        """The candidate pool of ``mesh``."""
        return sample_keypoints(mesh, self.num_keypoints, self.delta, self.num_samples, seed=self.seed)

    def protected_vertices(self, mesh: trimesh.Trimesh) -> np.ndarray:
        """``(P,)`` vertices inside the protected regions."""
        return region_vertices(np.asarray(mesh.vertices), self.protected)

    def handle_set(self, mesh: trimesh.Trimesh, kp: Keypoints, chosen: np.ndarray, notes: dict) -> HandleSet:
        """Build the HandleSet from chosen keypoint numbers (indices into ``kp``, ``(H,)``)."""
        protected = self.protected_vertices(mesh)
        handles = kp.vertices[np.asarray(chosen, np.int64)]
        dropped = np.intersect1d(handles, protected)
        handles = np.setdiff1d(handles, protected)
        if len(handles) == 0:
            raise ValueError("every chosen handle lies in a protected region; loosen selector.protected")
        anchors = choose_anchors(mesh, handles, kp.vertices, protected, self.far_anchors, self.min_anchors)
        notes = {"selector": self.name, "keypoints": kp.vertices.tolist(),
                 "keypoint_stages": kp.stages.tolist(), "chosen_keypoints": [int(c) for c in chosen],
                 "protected_vertices": int(len(protected)), "dropped_protected_handles": dropped.tolist(),
                 **notes}
        return HandleSet(handles, anchors, notes).check(len(mesh.vertices))


class HeuristicSelector(KeypointSelector):
    """``k`` handles drawn uniformly (seeded) from the candidate keypoints.

    Args:
        k: handles drawn (clipped to the pool size); the paper matches it to the VLM's mean count.
        **kwargs: see :class:`KeypointSelector`.
    """

    name = "heuristic"

    def __init__(self, k: int = 8, **kwargs):
        super().__init__(**kwargs)
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        self.k = int(k)

    def select(self, mesh: trimesh.Trimesh, task: str) -> HandleSet:
        """See :meth:`HandleSelector.select`; ``task`` is recorded in the notes only."""
        kp = self.keypoints(mesh)
        rng = np.random.default_rng(self.seed)
        chosen = np.sort(rng.choice(len(kp), size=min(self.k, len(kp)), replace=False))
        return self.handle_set(mesh, kp, chosen, {"task": task, "k": self.k, "seed": self.seed})
