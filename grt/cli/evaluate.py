"""``grt-evaluate`` (``python -m grt.evaluate object=NAME|PATH budget.trials=N``): score a policy on one object as it is.

The object is scored on the same episode seeds a red-team run with the same ``budget.seed`` uses, so
this reproduces a run's nominal score S0 (or re-scores a CrashShape file). The run folder gets
``evaluation.json`` (every trial); the console gets the figures and, as its last line, one JSON
object: ``score, ci95, score_name, score_unit, ci, success_rate, trials, outcomes, wall_s, startup_s,
trials_s, trials_per_s, object, mesh_hash, swap_check, saved`` (``saved``: the path of ``evaluation.json``;
``swap_check``: a ManiSkill task's copy against its stock env, :mod:`grt.swapcheck`, whose stock trials run
beside the object's when the object is the task's own actor and the check is not cached). When every
trial ended in ``sim_error`` there is no score: one ``error:`` line with the first trial's reason, exit code 2. The
simulator workers are started first, with one line saying so; ``trials_per_s`` is the trials over
``trials_s``, the time after start-up that the progress bar measured, so the two rates agree. ``score`` is the task's score (the success rate of a binary task, the mean
opening of a drawer task...), its interval by the task's ``ci`` setting (:mod:`grt.scores`). The run folder
is made and locked before Hydra writes there (:class:`grt.cli.callbacks.RunFolderCallback`): a second process
given the same folder is refused with one line naming the first's PID, exit code 2.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from pathlib import Path

import hydra
import numpy as np
import trimesh
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from grt.agreement import SwapCheckSettings
from grt.cli._common import CONF_DIR, exit_on_user_error, run_cli
from grt.config import plain, validate
from grt.evaluators.base import NothingScoredError, check_scored, evaluator_preflight
from grt.evaluators.collision import CollisionError
from grt.geometry.mesh import check_object_size, load_mesh, mesh_hash
from grt.geometry.prepare import MeshSettings
from grt.geometry.prepare import describe as describe_preparation
from grt.redteam import episode_seeds
from grt.report.figures import swap_line
from grt.scores import ScoreSpec
from grt.swapcheck import check_settings, not_checked, swap_check
from grt.targets import build
from grt.tasks import ACTOR_OBJECT, check_fit, preflight, task_object

log = logging.getLogger(__name__)


def evaluate(cfg: DictConfig, output_dir: str | Path) -> dict:
    """Evaluate ``cfg.object`` with ``cfg.budget.trials`` trials; returns the summary (see module doc).

    Raises:
        grt.objects.UnknownObjectError: neither a built-in object nor an existing file.
        MeshError: an unreadable or unusable mesh file, or one not in meters (``object_scale``).
        NothingScoredError: every trial ended in ``sim_error`` (``evaluation.json`` is written first).
    """
    score = ScoreSpec.from_task(cfg.task)
    scale = cfg.get("object_scale", 1.0)
    check_fit(plain(cfg.task), plain(cfg.policy))  # no Vulkan, a policy of another kind: before the mesh
    mesh = load_mesh(task_object(cfg.task, cfg.object, cfg.paths.cache_dir), scale=scale,
                     settings=MeshSettings.from_config(cfg.get("mesh")))
    check_object_size(mesh)  # a mesh in millimetres: refused before any simulation
    print("\n".join(describe_preparation(mesh)), flush=True)  # every repair and the fidelity figures
    preflight(plain(cfg.task), plain(cfg.policy), mesh, scale)  # a policy of the wrong kind: refused first
    evaluator_preflight(plain(cfg.evaluator), plain(cfg.task), plain(cfg.policy))  # evaluator=gpu without CUDA, ...
    swap_settings = SwapCheckSettings.from_config(cfg.get("swap_check"))
    check_settings(plain(cfg.task), ACTOR_OBJECT, swap_settings)  # an override with nothing to override
    seeds = episode_seeds(cfg.budget.seed, cfg.budget.trials)
    output_dir = Path(output_dir)
    render_dir = str(output_dir / "renders") if cfg.get("render", False) else None
    start = time.perf_counter()
    parts, parts_dir = saved_parts(cfg.object, cfg.get("parts", "auto"), scale)
    if parts_dir is not None:
        print(f"collision     the {len(parts)} convex parts the red-team run simulated this shape with "
              f"({parts_dir}); parts=decompose runs CoACD on the file instead", flush=True)
    with build(cfg.evaluator, "evaluator", task=plain(cfg.task), policy=plain(cfg.policy), nominal=mesh,
               render_dir=render_dir) as ev:
        startup = ev.start() if hasattr(ev, "start") else 0.0  # one line before the silent start-up
        begin = time.perf_counter()
        swap, result = _swap_check(cfg, mesh, seeds, ev, swap_settings)  # the task's copy against its stock env
        ran = len(seeds) * (2 if result is not None else 1)  # the object's trials, and the stock actor's with them
        # the base Evaluator interface takes meshes and seeds; the simulator's also takes known parts
        if result is None:
            result = (ev.evaluate([mesh], seeds) if parts is None else ev.evaluate([mesh], seeds, parts=[parts]))[0]
        collision_s = ev.collision_s
        backend = ev.backend_info() if hasattr(ev, "backend_info") else None
        run_s = getattr(ev, "run_s", 0.0) or time.perf_counter() - begin  # what the progress bar timed
    wall = time.perf_counter() - start
    summary = {**result.summary(ci=score.ci), **score.fields(), "object": str(cfg.object),
               "mesh_hash": mesh_hash(mesh.vertices, mesh.faces),
               "mesh_preparation": mesh.metadata.get("grt_prepare"),
               "wall_s": round(wall, 3), "startup_s": round(startup, 3), "trials_s": round(run_s, 3),
               "worker_s": round(result.wall_s, 3), "trials_per_s": round(ran / run_s, 4) if run_s else None,
               "collision_s": round(collision_s, 4),
               "collision_parts": str(parts_dir) if parts_dir is not None else "coacd", "evaluator": backend,
               "swap_check": swap}
    output_dir.mkdir(parents=True, exist_ok=True)
    record = {**summary, "seeds": seeds, "trials": [asdict(t) for t in result.trials]}
    (output_dir / "evaluation.json").write_text(json.dumps(record, indent=1, default=str))
    summary["saved"] = str(output_dir / "evaluation.json")
    try:  # every trial a sim_error: no score ("success rate nan" and exit code 0 before), the first reason said
        check_scored(result, f"the object {cfg.object}")
    except NothingScoredError as err:
        raise NothingScoredError(f"{err}; every trial's reason is in {summary['saved']}") from None
    if render_dir and not any(Path(render_dir).glob("*.png")):
        log.warning("render=true, but the task session wrote no pictures (it has no render(path))")
    return summary


def _swap_check(cfg: DictConfig, mesh: trimesh.Trimesh, seeds: list[int], ev, settings: SwapCheckSettings):
    """The swap check of the task (:mod:`grt.swapcheck`) on the evaluation's seeds: ``(record, result)``, the
    result being the object's own when the object is the task's actor and the check scored it (else ``None``).
    For another object (a CrashShape file) the check runs with the task's own actor (cached from a red-team run
    on the same seeds)."""
    task, policy = plain(cfg.task), plain(cfg.policy)
    own = str(cfg.object) == ACTOR_OBJECT
    if not_checked(task, ACTOR_OBJECT) is not None:
        return swap_check(task, policy, str(cfg.object), mesh, seeds, ev, settings, cfg.paths.cache_dir)[0], None
    actor = mesh if own else load_mesh(task_object(cfg.task, ACTOR_OBJECT, cfg.paths.cache_dir),
                                       settings=MeshSettings.from_config(cfg.get("mesh")))
    swap, result = swap_check(task, policy, ACTOR_OBJECT, actor, seeds, ev, settings, cfg.paths.cache_dir,
                              plain(cfg.evaluator))
    if swap["stock"] is not None:
        print(swap_line({"swap_check": swap}), flush=True)
    return swap, result if own else None


def saved_parts(spec: str, mode: str, scale: float = 1.0) -> tuple[list | None, Path | None]:
    """The convex parts saved beside a CrashShape file (``<stem>_parts/part*.obj``), or ``(None, None)``.

    A red-team run writes each CrashShape with the parts it was simulated with (:mod:`grt.outputs`);
    re-scoring the file with those reproduces the run's physics, where a fresh CoACD run on the file
    may cut the shape differently. ``mode``: ``auto`` (use them when present) or ``decompose`` (never).

    Raises:
        grt.evaluators.collision.CollisionError: an unknown ``mode``, or a parts folder without readable parts.
    """
    if mode not in ("auto", "decompose"):
        raise CollisionError(f"parts={mode!r} is not a setting: parts=auto (use a CrashShape's saved "
                         "<stem>_parts folder when there is one) or parts=decompose (run CoACD on the file)")
    path = Path(str(spec))
    folder = path.with_name(f"{path.stem}_parts")
    if mode == "decompose" or not path.suffix or not folder.is_dir():
        return None, None
    files = sorted(folder.glob("part*.obj"))
    try:
        parts = [np.asarray(trimesh.load(f, force="mesh").vertices, np.float64) * float(scale) for f in files]
    except Exception as err:  # noqa: BLE001 - any unreadable file is the same user problem
        raise CollisionError(f"{folder}: a part cannot be read ({type(err).__name__}: {err}); "
                         "use parts=decompose to run CoACD on the shape instead") from None
    if not parts or any(len(p) < 4 for p in parts):
        raise CollisionError(f"{folder} holds no usable convex parts; use parts=decompose to run CoACD on the "
                         "shape instead")
    return parts, folder


def figures(summary: dict) -> str:
    """The console lines of an :func:`evaluate` summary: the score by its name, unit and interval."""
    spec = ScoreSpec.from_summary(summary)
    low, high = summary["ci95"]
    fmt = (lambda v: f"{v:.3f}") if spec.binary else (lambda v: spec.fmt(v, unit=True))  # noqa: E731
    lines = [f"object        {summary['object']}  (mesh {summary['mesh_hash']})",
             f"{spec.label:<13} {fmt(summary['score'])}  95% CI [{fmt(low)}, {fmt(high)}] ({spec.ci})  "
             f"over {summary['trials']} trials"]
    if not spec.binary:
        lines.append(f"success rate  {summary['success_rate']:.3f}")
    lines += ["outcomes      " + ", ".join(f"{k}: {v}" for k, v in sorted(summary["outcomes"].items())),
              _timing(summary)]
    if swap_line(summary):
        lines.append(swap_line(summary))
    if summary.get("saved"):
        lines.append(f"saved         {summary['saved']}  (every trial)")
    return "\n".join(lines)


def _timing(summary: dict) -> str:
    """The wall line: start-up, the trials at the rate the progress bar showed, worker and collision time
    (a summary from before ``trials_s`` gives its one rate over the whole wall time)."""
    rate = summary.get("trials_per_s")
    rate_text = f"{rate:.3f} trials/s" if rate else "- trials/s"
    if "trials_s" not in summary:
        return (f"wall          {summary['wall_s']:.1f} s  ({rate_text}, worker time {summary['worker_s']:.1f} s, "
                f"collision {summary['collision_s'] * 1e3:.0f} ms)")
    return (f"wall          {summary['wall_s']:.1f} s: start-up {summary['startup_s']:.1f} s, trials "
            f"{summary['trials_s']:.1f} s ({rate_text}; worker time {summary['worker_s']:.1f} s), "
            f"collision {summary['collision_s'] * 1e3:.0f} ms")


@hydra.main(config_path=CONF_DIR, config_name="evaluate", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns the task's score (the success rate of a binary task)."""
    with exit_on_user_error():
        validate(cfg)
        summary = evaluate(cfg, HydraConfig.get().runtime.output_dir)
    print(figures(summary))
    print(json.dumps(summary))
    return float(summary["score"])


def cli() -> None:
    """``grt-evaluate``: a mistake in the command line or the config is one ``error:`` line, exit code 2."""
    run_cli(main)
