"""Handle selection: which vertices a deformation moves (handles) and keeps fixed (anchors).

``manual`` (user indices/regions), ``heuristic`` (uniform draw from the keypoint sampler's
candidates), ``all`` (every candidate), ``vlm`` (the paper's two-stage VLM prompting).
"""

from grt.selectors.base import HandleSelector, HandleSet

__all__ = ["HandleSelector", "HandleSet"]
