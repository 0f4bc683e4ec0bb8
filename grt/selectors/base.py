"""Handle/anchor sets and the selector interface (config group ``selector``).

A deformation displaces *handle* vertices and keeps *anchor* vertices fixed (paper, lines 219-225).
Every selector returns a :class:`HandleSet` of vertex indices of the mesh it was given; the two sets
are disjoint and there are at least three anchors (a rigid alignment on the anchors needs three).

Anchors rule shared by the keypoint-based selectors (:func:`choose_anchors`):
    anchors = candidate keypoints not chosen as handles
            + every vertex inside a protected region (``protected``, e.g. a plug's pins)
            + optionally ``far_anchors`` extra vertices far from the handles (farthest-point sampling),
    minus the handles; topped up with far-from-handle vertices until there are ``min_anchors`` (>= 3).
"""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from grt.errors import UserError

MIN_ANCHORS = 3


class SelectorError(UserError):
    """Handles or anchors the user gave that cannot be used (none, a region with no vertex, a bad file);
    the message names the setting and the fix."""


@dataclass(frozen=True)
class HandleSet:
    """Handles and anchors chosen on a mesh.

    Attributes:
        handles: ``(H,)`` int vertex indices to displace (unique, H >= 1).
        anchors: ``(A,)`` int vertex indices kept fixed (unique, disjoint from ``handles``).
        notes: JSON-serializable record of how the choice was made (selector, keypoints, VLM labels,
            fallback reasons, ...).
    """

    handles: np.ndarray
    anchors: np.ndarray
    notes: dict = field(default_factory=dict)

    def __post_init__(self):
        handles = np.asarray(self.handles, dtype=np.int64).reshape(-1)
        anchors = np.asarray(self.anchors, dtype=np.int64).reshape(-1)
        if len(handles) == 0:
            raise ValueError("a HandleSet needs at least one handle")
        if len(np.unique(handles)) != len(handles) or len(np.unique(anchors)) != len(anchors):
            raise ValueError("handle and anchor indices must be unique")
        both = np.intersect1d(handles, anchors)
        if len(both):
            raise ValueError(f"handles and anchors overlap at vertices {both.tolist()}")
        object.__setattr__(self, "handles", handles)
        object.__setattr__(self, "anchors", anchors)
        object.__setattr__(self, "notes", dict(self.notes))

    def check(self, num_vertices: int) -> HandleSet:
        """Raise ``ValueError`` unless every index is a vertex of a mesh with ``num_vertices``."""
        for name, idx in (("handle", self.handles), ("anchor", self.anchors)):
            bad = idx[(idx < 0) | (idx >= num_vertices)]
            if len(bad):
                raise ValueError(f"{name} indices {bad.tolist()} out of range for {num_vertices} vertices")
        return self

    def to_dict(self, mesh: trimesh.Trimesh | None = None) -> dict:
        """Plain dict; with ``mesh``, also ``handle_positions``/``anchor_positions`` in the mesh's units."""
        out = {"handles": self.handles.tolist(), "anchors": self.anchors.tolist(), "notes": self.notes}
        if mesh is not None:
            out["handle_positions"] = np.asarray(mesh.vertices)[self.handles].tolist()
            out["anchor_positions"] = np.asarray(mesh.vertices)[self.anchors].tolist()
        return out

    def to_json(self, mesh: trimesh.Trimesh | None = None) -> str:
        """JSON text of :meth:`to_dict`."""
        return json.dumps(self.to_dict(mesh), indent=2)

    @classmethod
    def from_json(cls, source: str | Path) -> HandleSet:
        """Read a HandleSet from JSON text or a JSON file (``handles``, ``anchors``, optional ``notes``)."""
        text = str(source)
        if not text.lstrip().startswith("{"):
            text = Path(text).expanduser().read_text()
        data = json.loads(text)
        return cls(data["handles"], data["anchors"], data.get("notes", {}))


class HandleSelector(ABC):
    """Chooses handles and anchors on a mesh for a task. Implementations never modify the mesh."""

    @abstractmethod
    def select(self, mesh: trimesh.Trimesh, task: str) -> HandleSet:
        """Choose handles and anchors.

        Args:
            mesh: the nominal object (meters), watertight (``grt.geometry.mesh.load_mesh``).
            task: natural-language task description (e.g. "grasp the object, lift it and shake it").

        Returns:
            A :class:`HandleSet` of vertex indices of ``mesh``.
        """


def farthest_vertices(vertices: np.ndarray, sources: np.ndarray, count: int, exclude: np.ndarray) -> np.ndarray:
    """Farthest-point sampling of ``count`` vertices away from ``sources``.

    Args:
        vertices: ``(V, 3)`` positions.
        sources: ``(S,)`` vertex indices to stay away from (the handles).
        count: vertices to pick.
        exclude: ``(E,)`` vertex indices never picked.

    Returns:
        ``(<= count,)`` picked vertex indices, farthest first.
    """
    dist = np.full(len(vertices), np.inf)
    for s in sources:
        dist = np.minimum(dist, np.linalg.norm(vertices - vertices[s], axis=1))
    dist[np.asarray(exclude, np.int64)] = -np.inf
    picked: list[int] = []
    for _ in range(count):
        j = int(np.argmax(dist))
        if not np.isfinite(dist[j]) or dist[j] < 0:
            break
        picked.append(j)
        dist = np.minimum(dist, np.linalg.norm(vertices - vertices[j], axis=1))
        dist[j] = -np.inf
    return np.asarray(picked, dtype=np.int64)


def choose_anchors(mesh: trimesh.Trimesh, handles: np.ndarray, candidates: np.ndarray,
                   protected: np.ndarray | None = None, far_anchors: int = 0,
                   min_anchors: int = MIN_ANCHORS) -> np.ndarray:
    """The anchors rule of the module docstring.

    Args:
        mesh: the object (not modified).
        handles: ``(H,)`` chosen handle vertices.
        candidates: ``(K,)`` candidate keypoint vertices (those not in ``handles`` become anchors).
        protected: ``(P,)`` vertices the task keeps fixed (all become anchors).
        far_anchors: extra anchors far from the handles.
        min_anchors: the fewest anchors returned (at least 3).

    Returns:
        ``(A,)`` sorted unique anchor vertex indices, disjoint from ``handles``, ``A >= min_anchors``.
    """
    handles = np.asarray(handles, np.int64)
    parts = [np.asarray(candidates, np.int64), np.asarray(protected if protected is not None else [], np.int64)]
    anchors = np.setdiff1d(np.concatenate(parts), handles)
    vertices = np.asarray(mesh.vertices)
    extra = max(int(far_anchors), max(int(min_anchors), MIN_ANCHORS) - len(anchors))
    if extra > 0:
        far = farthest_vertices(vertices, handles, extra, np.concatenate([handles, anchors]))
        anchors = np.union1d(anchors, far)
    if len(anchors) < MIN_ANCHORS:
        raise ValueError(f"only {len(anchors)} anchors possible on a mesh with {len(vertices)} vertices "
                         f"and {len(handles)} handles; at least {MIN_ANCHORS} are needed")
    return anchors
