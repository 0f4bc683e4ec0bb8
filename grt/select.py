"""Choose handles and anchors on one object: ``python -m grt.select object=NAME|PATH selector=...``.

Writes into Hydra's run folder, as ``grt.run`` does (``hydra.run.dir=PATH``, or ``out_dir=PATH`` for
short; ``outputs/select/<object>/<selector>/<time>`` by default): ``handles.json`` (vertex indices,
positions in meters, and the VLM's semantic label and expected transformations when there are some)
and ``panel.png`` (the canonical view panel of the candidate keypoints, chosen handles outlined in red;
for the VLM selector the same keypoints, numbers and views the model saw), then prints the choice. A
mistake (unknown object, bad mesh, missing API key, unwritable folder) is one ``error:`` line and exit
code 2.
"""

from __future__ import annotations

import json
from pathlib import Path

import hydra
import numpy as np
import trimesh
from omegaconf import DictConfig

import grt.config  # registers the object_name resolver used in conf/select.yaml
from grt.errors import OutputError, exit_on_user_error, run_cli, write_output
from grt.geometry.mesh import UnitCubeFrame, check_object_size, load_mesh
from grt.geometry.prepare import MeshSettings
from grt.geometry.prepare import describe as describe_preparation
from grt.selectors.base import HandleSet
from grt.selectors.panel import render_panel


def panel_png(mesh: trimesh.Trimesh, result: HandleSet) -> bytes:
    """Panel of the candidate keypoints (``notes["keypoints"]``) or, without them, of the handles."""
    points = np.asarray(result.notes.get("keypoints") or result.handles, dtype=np.int64)
    frame = UnitCubeFrame.fit(np.asarray(mesh.vertices))
    unit = frame.to_unit(mesh.vertices)
    return render_panel(unit, mesh.faces, unit[points], highlight=np.isin(points, result.handles))


def select(object_spec: str, task: str, selector, out_dir: str | Path, object_scale: float = 1.0,
           mesh_settings: MeshSettings | None = None) -> dict:
    """Run a selector on an object and write ``handles.json`` and ``panel.png``.

    Args:
        object_spec: a built-in object name or a mesh file path (meters).
        task: the task description.
        selector: a :class:`grt.selectors.base.HandleSelector`.
        out_dir: output folder (created).
        object_scale: meters per mesh unit (0.001 for a mesh in millimetres).
        mesh_settings: how the mesh is prepared (``None``: no remeshing); the indices in ``handles.json``
            are those of the prepared mesh.

    Returns:
        The ``handles.json`` record (with ``mesh_preparation``: repairs, remesh, fidelity figures).

    Raises:
        grt.objects.UnknownObjectError, grt.geometry.mesh.MeshError: a bad object (or one not in meters).
        grt.errors.OutputError: a folder that cannot be created or written.
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create {out}: {exc.strerror}; choose a folder you can write to "
                          "(out_dir=PATH)") from None
    mesh = load_mesh(object_spec, scale=object_scale, settings=mesh_settings)
    check_object_size(mesh)
    print("\n".join(describe_preparation(mesh)), flush=True)  # every repair and the fidelity figures
    result = selector.select(mesh, task)
    record = {"object": str(object_spec), "task": task, "selector": type(selector).__name__,
              **result.to_dict(mesh)}
    record["units"] = "positions in meters (the object's frame); indices are mesh vertex indices"
    record["mesh_preparation"] = mesh.metadata.get("grt_prepare")
    for key in ("semantic_object_label", "expected_transformations"):
        if key in result.notes:
            record[key] = result.notes[key]
    write_output(out / "handles.json", json.dumps(record, indent=2), "out_dir=PATH")
    write_output(out / "panel.png", panel_png(mesh, result), "out_dir=PATH")
    return record


def describe(record: dict, out_dir: str | Path) -> str:
    """A short human-readable summary of a ``handles.json`` record."""
    lines = [f"{record['selector']} on {record['object']!r} for task {record['task']!r}:",
             f"  handles ({len(record['handles'])}): {record['handles']}",
             f"  anchors ({len(record['anchors'])}): {record['anchors']}"]
    if "semantic_object_label" in record:
        lines.append(f"  part: {record['semantic_object_label']}; "
                     f"transformations: {'; '.join(record['expected_transformations'])}")
    if "fallback" in record["notes"]:
        lines.append(f"  FALLBACK to heuristic: {record['notes']['fallback']['reason']}")
    lines.append(f"  wrote {Path(out_dir) / 'handles.json'} and {Path(out_dir) / 'panel.png'}")
    return "\n".join(lines)


@hydra.main(version_base="1.3", config_path="../conf", config_name="select")
def main(cfg: DictConfig) -> None:
    """Hydra entry point (conf/select.yaml): writes into Hydra's run folder, as ``grt.run``."""
    with exit_on_user_error():
        grt.config.validate(cfg)
        out_dir = Path(cfg.paths.output_dir)
        selector = hydra.utils.instantiate(cfg.selector)
        record = select(cfg.object, cfg.task, selector, out_dir, cfg.get("object_scale", 1.0),
                        MeshSettings.from_config(cfg.get("mesh")))
    print(describe(record, out_dir))


if __name__ == "__main__":
    run_cli(main)
