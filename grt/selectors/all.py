"""All-candidates handle selection: every heuristic keypoint is a handle.

The paper's "All Handles + Optimization" baseline (lines 408-410): more expressive, larger search.
"""

from __future__ import annotations

import numpy as np
import trimesh

from grt.selectors.base import HandleSet
from grt.selectors.heuristic import KeypointSelector


class AllSelector(KeypointSelector):
    """Every candidate keypoint (outside protected regions) is a handle.

    With no candidate left over, the anchors are the ``far_anchors`` (default 8) vertices farthest
    from the handles plus the protected vertices; see :class:`KeypointSelector` for the arguments.
    """

    name = "all"

    def __init__(self, far_anchors: int = 8, **kwargs):
        super().__init__(far_anchors=far_anchors, **kwargs)

    def select(self, mesh: trimesh.Trimesh, task: str) -> HandleSet:
        """See :meth:`HandleSelector.select`; ``task`` is recorded in the notes only."""
        kp = self.keypoints(mesh)
        return self.handle_set(mesh, kp, np.arange(len(kp)), {"task": task})
