"""Manual handle selection: vertex indices or regions, from config or a JSON file.

The paper's fallback where the VLM has no prior (e.g. USB connectors, lines 245-248): the user
encodes domain knowledge directly. Regions are boxes, spheres or named built-in regions
(``"mug:handle"``), see :mod:`grt.selectors.regions`.
"""

from __future__ import annotations

import json
import numbers
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh

from grt.selectors.base import MIN_ANCHORS, HandleSelector, HandleSet, SelectorError, farthest_vertices
from grt.selectors.regions import RegionSpec, region_vertices

FILE_KEYS = ("handles", "anchors", "handle_regions", "anchor_regions")
NO_HANDLES = ("selector=manual needs handles: give vertex indices (selector.handles='[12,40]'), regions "
              "(selector.handle_regions='[mug:handle]' or boxes/spheres in meters) or a file "
              "(selector.file=handles.json); a task may give defaults (task.manual: insertion, drawer)")


class ManualSelector(HandleSelector):
    """Handles and anchors given by the user.

    Handles are the union of ``handles`` and the vertices inside ``handle_regions``; anchors the
    union of ``anchors`` and the vertices inside ``anchor_regions``. When no anchors are given at all,
    the anchors are the ``far_anchors`` vertices farthest from the handles (farthest-point sampling).
    A handle region with more than ``max_per_region`` vertices is thinned by farthest-point sampling
    (a whole mug handle is hundreds of vertices; each handle adds three search dimensions); anchor
    regions are taken whole.

    Args:
        handles: handle vertex indices.
        anchors: anchor vertex indices.
        handle_regions: region specs whose vertices become handles.
        anchor_regions: region specs whose vertices become anchors.
        file: a JSON file with any of the keys ``handles``, ``anchors``, ``handle_regions``,
            ``anchor_regions`` (a ``handles.json`` written by ``python -m grt.select`` works);
            its entries are added to those given as arguments.
        far_anchors: anchors chosen when none are given (at least 3).
        max_per_region: the most vertices taken from one region (``None``: all).

    Raises:
        SelectorError: an unreadable ``file`` (when built); (at ``select``) no handles, a region with no
            vertex, an index out of range, or handles and anchors overlap.
    """

    def __init__(self, handles: Sequence[int] = (), anchors: Sequence[int] = (),
                 handle_regions: Sequence[RegionSpec] = (), anchor_regions: Sequence[RegionSpec] = (),
                 file: str | None = None, far_anchors: int = 8, max_per_region: int | None = None):
        spec = {"handles": list(handles), "anchors": list(anchors),
                "handle_regions": list(handle_regions), "anchor_regions": list(anchor_regions)}
        if file:
            data = _read_file(file)
            unknown = set(data) - set(FILE_KEYS) - {"notes", "handle_positions", "anchor_positions",
                                                   "object", "task", "selector"}
            if unknown:
                raise SelectorError(f"selector.file={file}: unknown keys {sorted(unknown)}; expected {FILE_KEYS}")
            for key in FILE_KEYS:
                spec[key] += list(data.get(key, []))
        for key in ("handles", "anchors"):
            _check_indices(key, spec[key], file)
        self.spec = spec
        self.file = file
        self.far_anchors = max(int(far_anchors), MIN_ANCHORS)
        self.max_per_region = max_per_region

    def _regions(self, vertices: np.ndarray, specs: list, thin: bool = True) -> np.ndarray:
        picked = []
        for spec in specs:
            idx = region_vertices(vertices, [spec])
            if len(idx) == 0:
                raise SelectorError(f"region {spec!r} contains no vertex of the mesh (check its units: meters)")
            if thin and self.max_per_region is not None and len(idx) > self.max_per_region:
                local = farthest_vertices(vertices[idx], [int(np.argmin(idx))], self.max_per_region, [])
                idx = idx[local]
            picked.append(idx)
        return np.concatenate(picked) if picked else np.zeros(0, np.int64)

    def select(self, mesh: trimesh.Trimesh, task: str) -> HandleSet:
        """See :meth:`HandleSelector.select`; ``task`` is recorded in the notes only."""
        vertices = np.asarray(mesh.vertices)
        handles = np.unique(np.concatenate([np.asarray(self.spec["handles"], np.int64),
                                            self._regions(vertices, self.spec["handle_regions"])]))
        if len(handles) == 0:
            raise SelectorError(NO_HANDLES)
        anchors = np.unique(np.concatenate([np.asarray(self.spec["anchors"], np.int64),
                                            self._regions(vertices, self.spec["anchor_regions"], thin=False)]))
        source = "given"
        if len(anchors) == 0:
            anchors = np.sort(farthest_vertices(vertices, handles, self.far_anchors, handles))
            source = f"{len(anchors)} vertices farthest from the handles"
        notes = {"selector": "manual", "task": task, "anchors_from": source, "file": self.file}
        try:
            return HandleSet(handles, anchors, notes).check(len(vertices))
        except ValueError as exc:  # indices the user gave: out of range, or a vertex both handle and anchor
            raise SelectorError(f"selector=manual: {exc}; fix selector.handles / selector.anchors "
                                "(or their regions)") from None


def _check_indices(key: str, values: list, file: str | None) -> None:
    """Refuse a ``handles`` / ``anchors`` entry that is not a vertex index (an integer >= 0): ``1.5`` would
    have been truncated to vertex 1 and ``[1, 2]`` failed deep in numpy.

    Raises:
        SelectorError: names the entry, where it came from and what is expected.
    """
    for value in values:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 0:
            where = f"selector.{key}" + (f" (with selector.file={file})" if file else "")
            raise SelectorError(f"{where}: {value!r} is not a vertex index; give integers >= 0, e.g. "
                                f"selector.{key}=[12,40], or regions (selector.{key[:-1]}_regions)")


def _read_file(file: str) -> dict:
    """The JSON object of ``selector.file``, or one line saying why it cannot be used."""
    path = Path(file).expanduser()
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise SelectorError(f"selector.file={file}: {exc.strerror or exc}; give an existing JSON file (a "
                            "handles.json written by python -m grt.select works)") from None
    except ValueError as exc:
        raise SelectorError(f"selector.file={file} is not valid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise SelectorError(f"selector.file={file} holds a JSON {type(data).__name__}, not an object with "
                            f"the keys {', '.join(FILE_KEYS)}")
    return data
