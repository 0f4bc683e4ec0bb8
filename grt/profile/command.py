"""``profile(cfg, out_dir) -> dict``: one robustness profile, as the ``grt-profile`` app and tests call it.

With ``run=RUN`` it takes the run's task, object, handles, deformer, collision settings and CrashShapes (the
adversarial directions) and, unless ``policy=`` is given, its policy; without a run, the object, task and
policy of the command, handles from its selector and random deformations alone. Everything that can be
refused is refused before the first simulation (:class:`ProfileError`, one line): a run with no CrashShape, a
run of another task or object than the command names, a size ladder that is empty, not positive or beyond
what the deformer keeps plausible.
"""

from __future__ import annotations

import json
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from grt.config import saved_plan
from grt.config.records import ConfigView
from grt.confirm import fresh_seeds
from grt.console import progress
from grt.evaluators.base import evaluator_preflight
from grt.fileio import atomic_path, write_text_atomic
from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import check_object_size, load_mesh
from grt.geometry.prepare import MeshSettings
from grt.journal import Journal
from grt.optimizers.smoothness import budget_tau
from grt.outputs import git_state
from grt.plan import DeformerPlan, RunPlan, dotted, object_name
from grt.profile import PROFILE_JSON, PROFILE_PNG
from grt.profile.measure import Direction, measure, plan
from grt.profile.shapes import ProfileError, check_sizes, default_sizes, largest_mm
from grt.redteam import episode_seeds
from grt.runfolder.record import is_run_folder, load_run_config
from grt.scores import ScoreSpec, crash_margin
from grt.selectors.base import HandleSet
from grt.targets import build
from grt.tasks import preflight, task_description, task_object

_STREAM = 0x70726F66  # "prof": the profile's fresh seeds
# keys of the command that name what a run already fixes: given with run=, they must be the run's
RUN_FIXES = ("task", "object", "object_scale", "mesh", "deformer", "selector")


@dataclass
class Setup:
    """What a profile measures: the task and policy configs (plain), names, the deformer over the handles, the
    Smoothness-Score cap (m), the adversarial directions, the episodes to keep apart, the evaluator config and
    the plausibility check."""

    task: dict
    policy: dict
    policy_name: str
    object: str
    deformer: ShapeDeformer
    tau: float | None
    directions: list[Direction]
    exclude: list[int]
    evaluator: dict
    validity: object


def profile(cfg: Mapping, out_dir: Path, given: tuple[str, ...] = (), policy_choice: str = "") -> dict:
    """Measure and write the profile (``profile.json``, ``profile.png``, ``profile.jsonl``) into ``out_dir``.

    Args:
        cfg: the composed ``conf/profile.yaml``, plain.
        out_dir: the profile's folder.
        given: the keys the command line set (``object``, ``policy``, ``task.session.x`` ...): with a run,
            :data:`RUN_FIXES` given must name the run's own.
        policy_choice: the name of the command's policy option (``antipodal``).

    Returns:
        What ``profile.json`` holds.
    """
    start = time.perf_counter()
    setup = _from_run(cfg, given, policy_choice) if cfg["run"] else _from_command(cfg, policy_choice)
    deformer, score, settings = setup.deformer, ScoreSpec.from_task(setup.task), cfg["profile"]
    sizes = check_sizes(settings["sizes"]) if settings["sizes"] is not None else default_sizes(
        float(np.linalg.norm(deformer.mesh.extents)) * 1000, setup.tau * 1000 if setup.tau else None,
        max((largest_mm(deformer, d.theta) for d in setup.directions), default=None))
    directions = setup.directions[:int(settings["directions"])]
    shapes = plan(deformer, sizes, int(settings["shapes"]), int(settings["seed"]), directions, setup.validity,
                  given=settings["sizes"] is not None)  # refuses sizes beyond plausibility, before simulating
    for note in shapes.notes:
        print(f"note: {note}", flush=True)
    seeds = fresh_seeds(int(settings["seed"]), int(settings["trials"]), setup.exclude, _STREAM)
    evaluator = build(setup.evaluator, "evaluator", task=setup.task, policy=setup.policy,
                      nominal=deformer.mesh, progress=False)
    count = 1 + sum(len(t) for _, t, _ in shapes.random) + sum(len(levels) for _, levels, _ in shapes.directions)
    try:
        if hasattr(evaluator, "start"):
            evaluator.start()
        with progress(count, "profile", "shape") as bar:
            result = measure(out_dir, shapes, deformer, evaluator, seeds, crash_margin(setup.task), score.binary,
                             score.ci, int(settings["rounds"]), on_done=lambda: bar.update(1))
    finally:
        evaluator.close()
    out = {"task": setup.task["name"], "object": setup.object, "policy": setup.policy_name,
           "run": str(cfg["run"]) if cfg["run"] else None, "tau_mm": setup.tau * 1000 if setup.tau else None,
           "diagonal_mm": round(float(np.linalg.norm(deformer.mesh.extents)) * 1000, 2),
           "size_measure": "largest displacement of any surface point from the nominal object (mm)",
           "sizes_mm": shapes.sizes, "shapes": int(settings["shapes"]), "trials": len(seeds), "seeds": seeds,
           "seed": int(settings["seed"]), "score_name": score.name, "score_unit": score.unit, "notes": shapes.notes,
           **result, "wall_s": round(time.perf_counter() - start, 1), "git": git_state()}
    _write(out_dir, out)
    return out


def _from_command(cfg: Mapping, policy_choice: str) -> Setup:
    """The profile's :class:`Setup` without a run: random deformations of the command's object."""
    task, policy, budget, deformer_plan = cfg["task"], cfg["policy"], cfg["budget"], DeformerPlan.of(cfg["deformer"])
    mesh = load_mesh(task_object(task, cfg["object"], cfg["paths"]["cache_dir"]), scale=cfg["object_scale"],
                     settings=MeshSettings.from_config(cfg["mesh"]))
    check_object_size(mesh)
    preflight(task, policy, mesh, cfg["object_scale"])
    evaluator_preflight(cfg["evaluator"], task, policy)
    handles = build(cfg["selector"], "selector").select(mesh, task_description(task))
    deformer = ShapeDeformer(mesh, handles.handles, handles.anchors, **deformer_plan.options)
    tau = budget_tau(budget["tau"], budget.get("tau_rel"), float(np.linalg.norm(mesh.extents)))[0]
    exclude = episode_seeds(int(budget["seed"]), int(budget["trials"]))
    return Setup(task, policy, policy_choice, object_name(str(cfg["object"])), deformer, tau, [], exclude,
                 dict(cfg["evaluator"]), deformer_plan.check)


def _from_run(cfg: Mapping, given: tuple[str, ...], policy_choice: str) -> Setup:
    """The profile's :class:`Setup` from a red-team run folder (see the module doc)."""
    run_dir = Path(cfg["run"])
    if not is_run_folder(run_dir) or not (run_dir / "journal.jsonl").is_file() or not (run_dir / "handles.json").is_file():
        raise ProfileError(f"run={run_dir} is not a red-team run folder (it needs run_config.yaml, handles.json and "
                           "journal.jsonl); give run=outputs/<task>/<object>/<policy>/<selector>-<optimizer>/<time>, or "
                           "leave run= out to profile random deformations of object=... alone")
    run = saved_plan(load_run_config(run_dir), run_dir)
    _check_same(cfg, run, given)
    summary = json.loads((run_dir / "summary.json").read_text()) if (run_dir / "summary.json").is_file() else {}
    records = Journal(run_dir / "journal.jsonl").records
    directions = _directions(summary, records)
    if not directions:
        raise ProfileError(f"run={run_dir} found no CrashShape ({summary.get('note') or 'no summary.json'}), so there "
                           "is no adversarial direction to profile: profile random deformations alone with the run's "
                           f"task and object and no run= (task={run.task['name']} object={run.object}), or "
                           "red-team longer first")
    task = run.task
    own = any(_under(k, "policy") for k in given)
    policy = cfg["policy"] if own else run.policy
    mesh = load_mesh(task_object(task, run.object, cfg["paths"]["cache_dir"]), scale=run.object_scale, settings=run.mesh)
    preflight(task, policy, mesh, run.object_scale)
    handles = HandleSet.from_json((run_dir / "handles.json").read_text())
    deformer = ShapeDeformer(mesh, handles.handles, handles.anchors, **run.deformer.options)
    evaluator = dict(cfg["evaluator"])
    for key in ("collision", "coacd", "max_hull_vertices"):  # the run's collision geometry
        if key in run.evaluator:
            evaluator[key] = run.evaluator[key]
    evaluator_preflight(evaluator, task, policy)
    return Setup(task, policy, policy_choice if own else str(summary.get("policy", "?")),
                 run.object_name, deformer, summary.get("tau"), directions, _run_episodes(run, summary), evaluator,
                 run.deformer.check)


def _check_same(cfg: Mapping, run: RunPlan, given: tuple[str, ...]) -> None:
    """Refuse a command that names another task or object (or mesh, deformer, handles) than the run's."""
    saved = ConfigView(run.config)
    for key in RUN_FIXES:
        if not any(_under(k, key) for k in given):
            continue
        mine = dotted(cfg, key if key != "task" else "task.name")
        theirs = saved.get(key if key != "task" else "task.name")
        if key == "object":
            mine, theirs = object_name(str(mine)), object_name(str(theirs))
        if mine != theirs:
            raise ProfileError(f"run={run.run_dir} is a run of task {run.task['name']} on {run.object_name}"
                               f"; {key}={mine} is another {'task' if key == 'task' else key}: its CrashShapes "
                               f"are shapes of that run's {key}. Profile it without run= (random deformations alone), "
                               "or give a run of it")


def _directions(summary: dict, records: list[dict]) -> list[Direction]:
    """The run's CrashShapes as adversarial directions: confirmed ones first (by rank), then the others."""
    if not summary.get("crashshape_found"):
        return []
    thetas = {(r["iteration"], r["candidate"]): r["theta"] for r in records}
    fresh = {(c["iteration"], c["candidate"]): c["confirmed"] for c in (summary.get("confirm") or {}).get("shapes", [])}
    shapes = [Direction(e["rank"], e["iteration"], e["candidate"], np.asarray(thetas[e["iteration"], e["candidate"]]),
                        fresh.get((e["iteration"], e["candidate"]))) for e in summary.get("crashshapes", [])]
    return sorted(shapes, key=lambda d: (d.confirmed is not True, d.rank))


def _run_episodes(run: RunPlan, summary: dict) -> list[int]:
    """Every episode seed the run used: its search's, its confirmation's and its shrink's."""
    seeds = episode_seeds(run.budget.seed, run.budget.trials)
    return seeds + list((summary.get("confirm") or {}).get("seeds", [])) + list((summary.get("shrink") or {}).get("seeds", []))


def _under(key: str, prefix: str) -> bool:
    return key == prefix or key.startswith(f"{prefix}.") or key.startswith(f"{prefix}/")


def _write(out_dir: Path, out: dict) -> None:
    from grt.profile.plot import plot_profile

    write_text_atomic(out_dir / PROFILE_JSON, json.dumps(out, indent=1, allow_nan=True))
    with atomic_path(out_dir / PROFILE_PNG) as tmp:
        plot_profile(out, tmp)
