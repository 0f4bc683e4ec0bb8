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
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from grt.config import plain
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
from grt.plan import DeformerPlan, object_name
from grt.profile import PROFILE_JSON, PROFILE_PNG
from grt.profile.measure import Direction, measure, plan
from grt.profile.shapes import ProfileError, check_sizes, default_sizes, largest_mm
from grt.redteam import episode_seeds
from grt.runfolder import is_run_folder, load_run_config
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


def profile(cfg: DictConfig, out_dir: Path, given: tuple[str, ...] = (), policy_choice: str = "") -> dict:
    """Measure and write the profile (``profile.json``, ``profile.png``, ``profile.jsonl``) into ``out_dir``.

    Args:
        cfg: the composed ``conf/profile.yaml``.
        out_dir: the profile's folder.
        given: the keys the command line set (``object``, ``policy``, ``task.session.x`` ...): with a run,
            :data:`RUN_FIXES` given must name the run's own.
        policy_choice: the name of the command's policy option (``antipodal``).

    Returns:
        What ``profile.json`` holds.
    """
    start = time.perf_counter()
    setup = _from_run(cfg, given, policy_choice) if cfg.run else _from_command(cfg, policy_choice)
    deformer, score = setup.deformer, ScoreSpec.from_task(setup.task)
    sizes = check_sizes(cfg.profile.sizes) if cfg.profile.sizes is not None else default_sizes(
        float(np.linalg.norm(deformer.mesh.extents)) * 1000, setup.tau * 1000 if setup.tau else None,
        max((largest_mm(deformer, d.theta) for d in setup.directions), default=None))
    directions = setup.directions[:int(cfg.profile.directions)]
    shapes = plan(deformer, sizes, int(cfg.profile.shapes), int(cfg.profile.seed), directions, setup.validity,
                  given=cfg.profile.sizes is not None)  # refuses sizes beyond plausibility, before simulating
    for note in shapes.notes:
        print(f"note: {note}", flush=True)
    seeds = fresh_seeds(int(cfg.profile.seed), int(cfg.profile.trials), setup.exclude, _STREAM)
    evaluator = build(OmegaConf.create(setup.evaluator), "evaluator", task=setup.task, policy=setup.policy,
                      nominal=deformer.mesh, progress=False)
    count = 1 + sum(len(t) for _, t, _ in shapes.random) + sum(len(levels) for _, levels, _ in shapes.directions)
    try:
        if hasattr(evaluator, "start"):
            evaluator.start()
        with progress(count, "profile", "shape") as bar:
            result = measure(out_dir, shapes, deformer, evaluator, seeds, crash_margin(setup.task), score.binary,
                             score.ci, int(cfg.profile.rounds), on_done=lambda: bar.update(1))
    finally:
        evaluator.close()
    out = {"task": setup.task["name"], "object": setup.object, "policy": setup.policy_name,
           "run": str(cfg.run) if cfg.run else None, "tau_mm": setup.tau * 1000 if setup.tau else None,
           "diagonal_mm": round(float(np.linalg.norm(deformer.mesh.extents)) * 1000, 2),
           "size_measure": "largest displacement of any surface point from the nominal object (mm)",
           "sizes_mm": shapes.sizes, "shapes": int(cfg.profile.shapes), "trials": len(seeds), "seeds": seeds,
           "seed": int(cfg.profile.seed), "score_name": score.name, "score_unit": score.unit, "notes": shapes.notes,
           **result, "wall_s": round(time.perf_counter() - start, 1), "git": git_state()}
    _write(out_dir, out)
    return out


def _from_command(cfg: DictConfig, policy_choice: str) -> Setup:
    """The profile's :class:`Setup` without a run: random deformations of the command's object."""
    task, policy = plain(cfg.task), plain(cfg.policy)
    mesh = load_mesh(task_object(cfg.task, cfg.object, cfg.paths.cache_dir), scale=cfg.object_scale,
                     settings=MeshSettings.from_config(cfg.mesh))
    check_object_size(mesh)
    preflight(task, policy, mesh, cfg.object_scale)
    evaluator_preflight(plain(cfg.evaluator), task, policy)
    handles = build(cfg.selector, "selector").select(mesh, task_description(cfg.task))
    deformer = ShapeDeformer(mesh, handles.handles, handles.anchors, **DeformerPlan.of(cfg.deformer).options)
    tau = budget_tau(cfg.budget.tau, cfg.budget.get("tau_rel"), float(np.linalg.norm(mesh.extents)))[0]
    exclude = episode_seeds(int(cfg.budget.seed), int(cfg.budget.trials))
    return Setup(task, policy, policy_choice, object_name(str(cfg.object)), deformer, tau, [], exclude,
                 plain(cfg.evaluator), DeformerPlan.of(cfg.deformer).check)


def _from_run(cfg: DictConfig, given: tuple[str, ...], policy_choice: str) -> Setup:
    """The profile's :class:`Setup` from a red-team run folder (see the module doc)."""
    run_dir = Path(cfg.run)
    if not is_run_folder(run_dir) or not (run_dir / "journal.jsonl").is_file() or not (run_dir / "handles.json").is_file():
        raise ProfileError(f"run={run_dir} is not a red-team run folder (it needs run_config.yaml, handles.json and "
                           "journal.jsonl); give run=outputs/<task>/<object>/<policy>/<selector>-<optimizer>/<time>, or "
                           "leave run= out to profile random deformations of object=... alone")
    run_cfg = load_run_config(run_dir)
    _check_same(cfg, run_cfg, given, run_dir)
    summary = json.loads((run_dir / "summary.json").read_text()) if (run_dir / "summary.json").is_file() else {}
    records = Journal(run_dir / "journal.jsonl").records
    directions = _directions(summary, records)
    if not directions:
        raise ProfileError(f"run={run_dir} found no CrashShape ({summary.get('note') or 'no summary.json'}), so there "
                           "is no adversarial direction to profile: profile random deformations alone with the run's "
                           f"task and object and no run= (task={run_cfg.task.name} object={run_cfg.object}), or "
                           "red-team longer first")
    task = plain(run_cfg.task)
    own = any(_under(k, "policy") for k in given)
    policy = plain(cfg.policy) if own else plain(run_cfg.policy)
    mesh = load_mesh(task_object(run_cfg.task, run_cfg.object, cfg.paths.cache_dir), scale=run_cfg.object_scale,
                     settings=MeshSettings.from_config(run_cfg.get("mesh")))
    preflight(task, policy, mesh, run_cfg.object_scale)
    handles = HandleSet.from_json((run_dir / "handles.json").read_text())
    deformer = ShapeDeformer(mesh, handles.handles, handles.anchors, **DeformerPlan.of(run_cfg.deformer).options)
    evaluator = plain(cfg.evaluator)
    for key in ("collision", "coacd", "max_hull_vertices"):  # the run's collision geometry
        if key in run_cfg.evaluator:
            evaluator[key] = plain(run_cfg.evaluator[key]) if isinstance(run_cfg.evaluator[key], DictConfig) \
                else run_cfg.evaluator[key]
    evaluator_preflight(evaluator, task, policy)
    return Setup(task, policy, policy_choice if own else str(summary.get("policy", "?")),
                 object_name(str(run_cfg.object)), deformer, summary.get("tau"), directions,
                 _run_episodes(run_cfg, summary), evaluator, DeformerPlan.of(run_cfg.deformer).check)


def _check_same(cfg: DictConfig, run_cfg: DictConfig, given: tuple[str, ...], run_dir: Path) -> None:
    """Refuse a command that names another task or object (or mesh, deformer, handles) than the run's."""
    for key in RUN_FIXES:
        if not any(_under(k, key) for k in given):
            continue
        mine = OmegaConf.select(cfg, key if key != "task" else "task.name", default=None)
        theirs = OmegaConf.select(run_cfg, key if key != "task" else "task.name", default=None)
        if key == "object":
            mine, theirs = object_name(str(mine)), object_name(str(theirs))
        if _plain(mine) != _plain(theirs):
            raise ProfileError(f"run={run_dir} is a run of task {run_cfg.task.name} on {object_name(str(run_cfg.object))}"
                               f"; {key}={_plain(mine)} is another {'task' if key == 'task' else key}: its CrashShapes "
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


def _run_episodes(run_cfg: DictConfig, summary: dict) -> list[int]:
    """Every episode seed the run used: its search's, its confirmation's and its shrink's."""
    seeds = episode_seeds(int(run_cfg.budget.seed), int(run_cfg.budget.trials))
    return seeds + list((summary.get("confirm") or {}).get("seeds", [])) + list((summary.get("shrink") or {}).get("seeds", []))


def _under(key: str, prefix: str) -> bool:
    return key == prefix or key.startswith(f"{prefix}.") or key.startswith(f"{prefix}/")


def _plain(value):
    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value


def _write(out_dir: Path, out: dict) -> None:
    from grt.profile.plot import plot_profile

    write_text_atomic(out_dir / PROFILE_JSON, json.dumps(out, indent=1, allow_nan=True))
    with atomic_path(out_dir / PROFILE_PNG) as tmp:
        plot_profile(out, tmp)
