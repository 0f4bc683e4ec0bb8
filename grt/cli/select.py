"""``grt-select`` (``python -m grt.select [task=NAME] object=NAME|PATH selector=...``): choose handles and anchors
on one object, for a task (``task=``, as ``grt.run`` takes it: its object by default, its description for the
VLM's prompt, its regions for ``selector=manual``).

Writes into Hydra's run folder, as ``grt.run`` does (``hydra.run.dir=PATH``, or ``out_dir=PATH`` for
short; ``outputs/select/<object>/<selector>/<time>`` by default): ``handles.json`` (vertex indices,
positions in meters, and the VLM's semantic label and expected transformations when there are some)
and ``panel.png`` (the canonical view panel of the candidate keypoints, chosen handles outlined in red;
for the VLM selector the same keypoints, numbers and views the model saw), then prints the choice.
With ``probe.sigmas=[...]`` it also answers, before any simulation, at which σ these handles fold the
object: :func:`probe_plausibility` deforms each search's first iteration at each σ and counts the
candidates ``grt.run`` would refuse as implausible (``probe.json``, and a table on screen). A
mistake (unknown object, bad mesh, missing API key, unwritable folder, a folder another GRT process holds:
:class:`grt.cli.callbacks.RunFolderCallback` locks it before Hydra writes there) is one ``error:`` line and exit
code 2.
"""

from __future__ import annotations

import json
from pathlib import Path

import hydra
import numpy as np
import trimesh
from omegaconf import DictConfig
from tqdm import tqdm

from grt.cli._common import CONF_DIR, exit_on_user_error, run_cli, write_output
from grt.config import ConfigError, validate
from grt.errors import OutputError
from grt.geometry.deform import ShapeDeformer, deformer_options
from grt.geometry.mesh import UnitCubeFrame, check_object_size, load_mesh
from grt.geometry.prepare import MeshSettings
from grt.geometry.prepare import describe as describe_preparation
from grt.geometry.quality import candidate_validity
from grt.optimizers.gaussian import GaussianOptimizer
from grt.optimizers.smoothness import project_to_budget
from grt.optimizers.topdm import TOPDMOptimizer
from grt.selectors.base import HandleSet
from grt.selectors.panel import render_panel
from grt.targets import build
from grt.tasks import task_description, task_object


def panel_png(mesh: trimesh.Trimesh, result: HandleSet) -> bytes:
    """Panel of the candidate keypoints (``notes["keypoints"]``) or, without them, of the handles."""
    points = np.asarray(result.notes.get("keypoints") or result.handles, dtype=np.int64)
    frame = UnitCubeFrame.fit(np.asarray(mesh.vertices))
    unit = frame.to_unit(mesh.vertices)
    return render_panel(unit, mesh.faces, unit[points], highlight=np.isin(points, result.handles))


def select(object_spec: str, task: str, selector, out_dir: str | Path, object_scale: float = 1.0,
           mesh_settings: MeshSettings | None = None, probe: dict | None = None,
           deformer: dict | None = None, task_name: str | None = None) -> dict:
    """Run a selector on an object and write ``handles.json`` and ``panel.png``.

    Args:
        object_spec: a built-in object name or a mesh file path (meters).
        task: the task description.
        selector: a :class:`grt.selectors.base.HandleSelector`.
        out_dir: output folder (created).
        object_scale: meters per mesh unit (0.001 for a mesh in millimetres).
        mesh_settings: how the mesh is prepared (``None``: no remeshing); the indices in ``handles.json``
            are those of the prepared mesh.
        probe: ``sigmas``, ``candidates``, ``seed``, ``tau`` of :func:`probe_plausibility`, whose rows go to
            ``probe.json`` and the record's ``probe`` (``None``: no probe).
        deformer: the deformer settings the probe uses (``grt.run``'s ``deformer`` block).
        task_name: the task's name (``task=NAME``), recorded with its description.

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
    record = {"object": str(object_spec), "task": task, **({"task_name": task_name} if task_name else {}),
              "selector": type(selector).__name__, **result.to_dict(mesh)}
    record["units"] = "positions in meters (the object's frame); indices are mesh vertex indices"
    record["mesh_preparation"] = mesh.metadata.get("grt_prepare")
    for key in ("semantic_object_label", "expected_transformations"):
        if key in result.notes:
            record[key] = result.notes[key]
    write_output(out / "handles.json", json.dumps(record, indent=2), "out_dir=PATH")
    write_output(out / "panel.png", panel_png(mesh, result), "out_dir=PATH")
    if probe:
        options = dict(deformer or {})
        rows = probe_plausibility(mesh, result, list(probe["sigmas"]), int(probe.get("candidates", 12)),
                                  int(probe.get("seed", 42)), probe.get("tau"), options)
        record["probe"] = {"handles": len(result.handles), "candidates": int(probe.get("candidates", 12)),
                           "seed": int(probe.get("seed", 42)), "tau": probe.get("tau"), "deformer": options,
                           "rows": rows}
        write_output(out / "probe.json", json.dumps(record["probe"], indent=2), "out_dir=PATH")
    return record


PROBE_SEARCHES = {"topdm": TOPDMOptimizer, "gaussian": GaussianOptimizer}


def check_probe(probe) -> None:
    """Refuse bad ``probe.*`` settings with one line (:class:`grt.errors.ConfigError`)."""
    sigmas = probe.get("sigmas") or []
    if isinstance(sigmas, (int, float, str)):
        raise ConfigError(f"probe.sigmas must be a list, got {sigmas!r}; e.g. 'probe.sigmas=[{sigmas}]'")
    sigmas = list(sigmas)
    if any(not isinstance(s, (int, float)) or not s > 0 for s in sigmas):
        raise ConfigError(f"probe.sigmas must be positive numbers (unit-cube units), got {sigmas}; "
                          "e.g. 'probe.sigmas=[0.02,0.03,0.06]'")
    if not isinstance(probe.get("candidates"), int) or probe.get("candidates") < 1:
        raise ConfigError(f"probe.candidates must be a whole number >= 1, got {probe.get('candidates')!r}")
    tau = probe.get("tau")
    if tau is not None and not (isinstance(tau, (int, float)) and tau > 0):
        raise ConfigError(f"probe.tau must be a positive number of meters or null, got {tau!r}")


def probe_plausibility(mesh: trimesh.Trimesh, result: HandleSet, sigmas, candidates: int = 12,
                       seed: int = 42, tau: float | None = None, deformer: dict | None = None,
                       progress: bool = True) -> list[dict]:
    """How many of a search's first-iteration candidates pass the validity checks, per σ and search.

    Exactly what ``grt.run`` would make at ``budget.population=candidates``, ``budget.seed=seed`` and
    ``budget.tau=tau`` (TOPDM perturbs half the handles, the Gaussian search all of them), deformed
    by the same :class:`ShapeDeformer` and judged by :func:`candidate_validity`; no simulation. A share
    well below 1 means the run will spend its budget on folded shapes it never simulates.

    Returns:
        One row per (search, σ): ``search``, ``sigma``, ``valid``, ``candidates``, ``self_intersecting``,
        ``inverted`` (candidates with any inverted face).
    """
    deform = ShapeDeformer(mesh, result.handles, result.anchors, **deformer_options(deformer or {}))
    rows = []
    jobs = [(name, float(s)) for name in PROBE_SEARCHES for s in sigmas]
    for name, sigma in tqdm(jobs, desc="probe", unit="σ", disable=not progress):
        search = PROBE_SEARCHES[name](num_handles=len(result.handles), population=candidates, sigma=sigma,
                                      seed=seed)
        thetas = project_to_budget(np.asarray(search.ask()), tau, deform.meters_per_unit)
        checks = [candidate_validity(deform.mesh, m) for m in deform.meshes(thetas)]
        rows.append({"search": name, "sigma": sigma, "valid": sum(bool(c["valid"]) for c in checks),
                     "candidates": len(checks),
                     "self_intersecting": sum(c.get("self_intersections", 0) > 0 for c in checks),
                     "inverted": sum(c.get("inverted_faces", 0) > 0 for c in checks)})
    return rows


def describe_probe(rows: list[dict]) -> str:
    """The probe as a small table: valid candidates of each search at each σ."""
    sigmas = sorted({r["sigma"] for r in rows})
    lines = ["plausible first-iteration candidates (valid / made; the rest grt.run refuses and never simulates):",
             "  search    " + "".join(f"σ {s:<9g}" for s in sigmas)]
    for name in PROBE_SEARCHES:
        cells = {r["sigma"]: f"{r['valid']}/{r['candidates']}" for r in rows if r["search"] == name}
        lines.append(f"  {name:<10}" + "".join(f"{cells.get(s, '-'):<11}" for s in sigmas))
    folding = sorted({r["sigma"] for r in rows if r["valid"] < r["candidates"] / 2})
    if folding:
        lines.append(f"  at σ {', '.join(f'{s:g}' for s in folding)} over half the candidates fold the object: "
                     "choose a smaller σ, a Smoothness-Score budget (budget.tau) or fewer handles")
    return "\n".join(lines)


def describe(record: dict, out_dir: str | Path) -> str:
    """A short human-readable summary of a ``handles.json`` record."""
    task = f"task={record['task_name']}" if record.get("task_name") else f"task {record['task']!r}"
    lines = [f"{record['selector']} on {record['object']!r} for {task}:",
             f"  handles ({len(record['handles'])}): {record['handles']}",
             f"  anchors ({len(record['anchors'])}): {record['anchors']}"]
    if "semantic_object_label" in record:
        lines.append(f"  part: {record['semantic_object_label']}; "
                     f"transformations: {'; '.join(record['expected_transformations'])}")
    if "fallback" in record["notes"]:
        lines.append(f"  FALLBACK to heuristic: {record['notes']['fallback']['reason']}")
    lines.append(f"  wrote {Path(out_dir) / 'handles.json'} and {Path(out_dir) / 'panel.png'}")
    return "\n".join(lines)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="select")
def main(cfg: DictConfig) -> None:
    """Hydra entry point (conf/select.yaml): writes into Hydra's run folder, as ``grt.run``."""
    with exit_on_user_error():
        validate(cfg, classes=("selector",))  # the task's session is not built here (it imports the simulator)
        probe = cfg.get("probe") or {}
        check_probe(probe)
        out_dir = Path(cfg.paths.output_dir)
        selector = build(cfg.selector, "selector")
        settings = MeshSettings.from_config(cfg.get("mesh"))
        record = select(task_object(cfg.task, cfg.object, cfg.paths.cache_dir), task_description(cfg.task), selector,
                        out_dir, cfg.get("object_scale", 1.0), settings,
                        probe=dict(probe) if probe.get("sigmas") else None, deformer=cfg.get("deformer"),
                        task_name=str(cfg.task.name))
    print(describe(record, out_dir))
    if record.get("probe"):
        print(describe_probe(record["probe"]["rows"]))
        print(f"  wrote {out_dir / 'probe.json'}")


def cli() -> None:
    """``grt-select``: a mistake in the command line or the config is one ``error:`` line, exit code 2."""
    run_cli(main)
