"""One red-team run as a plain function: ``run(cfg) -> summary``, which the ``grt-run`` app and tests call.

:func:`run` takes a composed (or, for a resume, the run's own) config: it prepares the object, saves the
run's record (:mod:`grt.runfolder`), selects handles, builds the deformer, optimizer and evaluator from the
config, runs :class:`grt.redteam.RedTeamLoop` (Algorithm 1), re-scores the CrashShapes on fresh episodes
when ``budget.confirm_trials`` > 0 (:mod:`grt.confirm`) and writes the run folder's outputs
(:mod:`grt.outputs`). The command line (Hydra, ``resume=``, Ctrl-C, sweeps) is :mod:`grt.cli.run`'s.
"""

from __future__ import annotations

import functools
import json
import logging
import shlex
import time
from pathlib import Path

import numpy as np
import trimesh
from omegaconf import DictConfig, ListConfig, OmegaConf

from grt.config import plain
from grt.confirm import confirm
from grt.console import progress
from grt.evaluators.base import NothingScoredError, evaluator_preflight
from grt.fileio import write_text_atomic
from grt.geometry.complexity import angular_deficit_entropy
from grt.geometry.deform import ShapeDeformer, deformer_options
from grt.geometry.mesh import check_object_size, load_mesh, mesh_hash
from grt.geometry.prepare import MeshSettings
from grt.geometry.prepare import describe as describe_preparation
from grt.geometry.quality import candidate_validity
from grt.journal import Journal
from grt.outputs import crash_records, print_summary, run_tau, save_nominal, write_outputs
from grt.policies.base import PolicyServerError
from grt.racing import Racing
from grt.redteam import RedTeamLoop, episode_seeds
from grt.runfolder import (
    RUN_CONFIG,
    ResumeError,
    load_run_config,
    locked,
    refuse_unless_run,
    resume_command,
    save_run_config,
    without_secrets,
)
from grt.scores import ScoreSpec, check_nominal_floor, crash_margin, nominal_floor
from grt.selectors.base import HandleSet
from grt.targets import build
from grt.tasks import preflight, task_description, task_object

log = logging.getLogger("grt.run")


def run(cfg: DictConfig) -> dict:
    """Run (or resume) one red-team run; returns its summary (also written to ``summary.json``).

    A resume of a finished run with nothing left to do (:func:`nothing_to_do`) says so and returns the run's
    summary, changing nothing.
    """
    run_dir = Path(cfg.resume or cfg.paths.output_dir)
    if cfg.resume:
        refuse_unless_run(run_dir)
        line = nothing_to_do(run_dir, cfg)
        if line is not None:
            print(line, flush=True)
            return json.loads((run_dir / "summary.json").read_text())
    score = ScoreSpec.from_task(cfg.task)  # a bad task.ci fails here, before any simulation
    floor = nominal_floor(cfg.task)
    crash_margin(cfg.task)  # a bad task.crash_margin fails here, before any simulation
    run_dir.mkdir(parents=True, exist_ok=True)
    with locked(run_dir):  # one process per run folder (grt.run's callback took it before Hydra wrote there)
        return _run(cfg, run_dir, score, floor)


def _run(cfg: DictConfig, run_dir: Path, score: ScoreSpec, floor) -> dict:
    start = time.perf_counter()
    scale = cfg.object_scale  # a resumed run's saved config is migrated (grt.runfolder): the key is there
    mesh = load_mesh(task_object(cfg.task, cfg.object, cfg.paths.cache_dir), scale=scale,
                     settings=MeshSettings.from_config(cfg.mesh))
    check_object_size(mesh)  # a mesh in millimetres: refused before any file
    if cfg.resume:
        check_same_object(run_dir, mesh, cfg)  # an edited record: refused before any file
    print("\n".join(describe_preparation(mesh)), flush=True)  # every repair and the fidelity figures
    preflight(plain(cfg.task), plain(cfg.policy), mesh, scale)  # wrong plug, policy kind or checkpoint: likewise
    evaluator_preflight(plain(cfg.evaluator), plain(cfg.task), plain(cfg.policy))  # evaluator=gpu without CUDA, ...
    # the user's classes are built before the run's record is saved: one that cannot be built is one line and
    # leaves no folder (grt.targets.build); the workers build the task's session as they start
    selector = None if (run_dir / "handles.json").exists() else build(cfg.selector, "selector")
    logger = build(cfg.logger, "logger")
    evaluator = build(cfg.evaluator, "evaluator", task=plain(cfg.task), policy=plain(cfg.policy), nominal=mesh,
                      progress=False)  # the red-team bar shows progress
    journal = Journal(run_dir / "journal.jsonl")
    total = 1 + cfg.budget.population * cfg.budget.iterations
    bar = None
    try:
        if len(journal) < total and hasattr(evaluator, "start"):
            evaluator.start()  # one line, then the workers' start-up, outside the bar's rate and ETA
        save_run_config(cfg, run_dir)
        handle_set = _select_handles(cfg, mesh, run_dir, selector)
        if not (run_dir / "nominal.obj").is_file():  # a resume's is the same mesh (check_same_object)
            save_nominal(run_dir, mesh)  # the mesh every CrashShape deforms (its vertex order, meters)
        deformer = ShapeDeformer(mesh, handle_set.handles, handle_set.anchors, **deformer_options(cfg.deformer))
        _announce_deformer(deformer)
        tau, how = run_tau(cfg, mesh)
        print(f"Smoothness-Score cap: {how}", flush=True)
        optimizer = build(cfg.optimizer, "optimizer", num_handles=len(handle_set.handles))
        seeds = episode_seeds(cfg.budget.seed, cfg.budget.trials)
        if journal.recovered_truncated_line:
            log.warning("journal: ignored a truncated last line (an interrupted write)")
        if len(journal):
            log.info("resuming %s: %d candidates already in the journal", run_dir, len(journal))
        folding = FoldingWatch(journal, len(handle_set.handles), cfg.budget.sigma)
        logger.start(run_dir, name=run_dir.name, config=without_secrets(cfg))
        bar = progress(total, "red-team", "cand", initial=len(journal))
        loop = RedTeamLoop(
            deformer, optimizer, evaluator, journal, seeds, cfg.budget.iterations, tau=tau,
            complexity=angular_deficit_entropy,
            on_candidate=lambda rec: _progress(bar, rec, score),
            on_iteration=lambda t, scores: (
                logger.log_iteration(t, {"best_score": optimizer.best_score, "mean_score": float(np.mean(scores))}),
                folding(t)),
            ci=score.ci, on_nominal=lambda s0: check_nominal_floor(s0, floor, score, resume_command(run_dir)),
            validity=_validity(cfg), racing=racing(cfg))
        try:
            result = loop.run()
            bar.close()
            confirmation = _confirm(cfg, run_dir, result, deformer, evaluator, seeds, score)
        except PolicyServerError as err:  # a served policy went away: the journal keeps what finished
            raise PolicyServerError(f"{err}; start the server again and finish the run: "
                                    f"{resume_command(run_dir)}") from None
        except NothingScoredError as err:  # e.g. a policy whose output the task cannot use: fixable, resumable
            raise NothingScoredError(f"{err}; fix that, then continue the run with: {resume_command(run_dir)}") \
                from None
        summary = write_outputs(cfg, run_dir, result, deformer, handle_set, evaluator,
                                wall_s=time.perf_counter() - start, confirmation=confirmation, score=score)
        logger.log_summary(summary)
        logger.log_images({"curve": run_dir / "curve.png", "shapes": run_dir / "shapes.png"})
        write_report(cfg, run_dir, summary, logger)
    finally:
        if bar is not None:
            bar.close()
        evaluator.close()
        logger.finish()
    print_summary(summary, run_dir)
    return summary


# Settings that make something after the search (a report's videos, a logger's record): given other values
# than the run had, a resume of a finished run has that to do.
AFTER_SEARCH = ("report", "budget.videos", "logger")


def nothing_to_do(run_dir: Path, cfg: DictConfig) -> str | None:
    """The line a resume of a finished run prints when ``cfg`` (its config as this command resolved it) asks
    for nothing new: every candidate in the journal, ``summary.json`` written, the confirmation on
    ``budget.confirm_trials`` fresh episodes done (or no CrashShape to confirm), the :data:`AFTER_SEARCH`
    settings the run's own. ``None`` when there is work (or the folder has a problem the run names itself)."""
    journal = run_dir / "journal.jsonl"
    try:
        summary = json.loads((run_dir / "summary.json").read_text())
        if not journal.read_bytes().endswith(b"\n"):  # empty, or an interrupted last line
            return None
        records = Journal(journal).records
        saved = load_run_config(run_dir)
    except Exception:  # noqa: BLE001 - a missing or broken file: the resume itself goes on or names it
        return None
    total = 1 + int(cfg.budget.population) * int(cfg.budget.iterations)
    if len(records) < total or any(_value(cfg, k) != _value(saved, k) for k in AFTER_SEARCH):
        return None
    trials = int(cfg.budget.confirm_trials or 0)
    if trials and (summary.get("confirm") or {}).get("trials") != trials:
        nominal = next((r for r in records if r["iteration"] == 0), None)
        if nominal is None or crash_records(records, cfg.budget.top_k, nominal["score"], crash_margin(cfg.task)):
            return None
    return (f"nothing to do: {run_dir} is a finished run ({len(records)} candidates in its journal, summary.json "
            f"written); nothing was changed. Its table: python -m grt.report {shlex.quote(str(run_dir))}; more "
            f"episodes for its CrashShapes: {resume_command(run_dir)} budget.confirm_trials=N")


def _value(cfg: DictConfig, key: str):
    value = OmegaConf.select(cfg, key, default=None, throw_on_resolution_failure=False)
    return OmegaConf.to_container(value, resolve=True) if isinstance(value, DictConfig | ListConfig) else value


def check_same_object(run_dir: Path, mesh, cfg: DictConfig) -> None:
    """Refuse a resume whose object (``cfg.object`` as loaded: ``mesh``) is not the one the run was made with
    (the journal's nominal line, else ``nominal.obj``), before anything is written: its record was edited.

    Raises:
        ResumeError: names the object settings and what to do.
    """
    journal = Journal(run_dir / "journal.jsonl") if (run_dir / "journal.jsonl").is_file() else None
    nominal = journal.get(0, 0) if journal is not None else None
    if nominal is not None:
        made_with = nominal["mesh_hash"]
    elif (run_dir / "nominal.obj").is_file():
        saved = trimesh.load(run_dir / "nominal.obj", process=False, force="mesh")
        made_with = mesh_hash(saved.vertices, saved.faces)
    else:
        return
    if mesh_hash(mesh.vertices, mesh.faces) != made_with:
        raise ResumeError(f"resume={run_dir}: the object its record gives (object={cfg.object}, object_scale="
                          f"{cfg.object_scale}, mesh settings) is not the object the run was made with (its "
                          f"nominal.obj and journal): its record ({RUN_CONFIG}) was edited. A run keeps the "
                          f"config it started with: restore {RUN_CONFIG}, or start a new run with this object "
                          "(the same command without resume=)")


def write_report(cfg: DictConfig, run_dir: Path, summary: dict, logger=None) -> None:
    """Film the top CrashShapes' failing trials (``report.videos``; rendering only here, after the search)
    and write ``report.html``. A report that fails is one warning: the run's results are already written."""
    from grt.report.html import write_run_report
    from grt.rerun import render_videos

    start = time.perf_counter()
    count = int(OmegaConf.select(cfg, "report.videos", default=0) or 0)
    try:
        index = render_videos(run_dir, summary, count) if count > 0 else None
        if index and index.get("skipped"):
            log.warning("report: no videos: %s", index["skipped"])
        path = write_run_report(run_dir)
    except Exception as exc:  # noqa: BLE001 - the run is done; say what failed and how to retry
        log.warning("report.html not written (%s: %s); python -m grt.report %s --html retries it",
                    type(exc).__name__, exc, shlex.quote(str(run_dir)))
        return
    if logger is not None and hasattr(logger, "log_report"):
        logger.log_report(run_dir, summary, index)
    print(f"report: {path} ({time.perf_counter() - start:.1f} s)", flush=True)


def racing(cfg: DictConfig) -> Racing | None:
    """The run's racing settings (``budget.racing``; ``None``: off, every candidate runs every trial)."""
    if not cfg.budget.get("racing"):
        return None
    return Racing(int(cfg.budget.race_rounds), float(cfg.budget.race_alpha), int(cfg.budget.top_k),
                  crash_margin(cfg.task))


def _validity(cfg: DictConfig):
    """The plausibility check of the run's candidates (``deformer.validity``, ``deformer.max_volume_change``)."""
    if not cfg.deformer.validity:
        return None
    bound = cfg.deformer.get("max_volume_change")
    return candidate_validity if bound is None else functools.partial(candidate_validity, max_volume_change=bound)


class FoldingWatch:
    """Warns once, at the first iteration whose candidates the validity checks all refused, that the
    search cannot move: a long run should not find that out only at its end."""

    def __init__(self, journal: Journal, handles: int, sigma: float):
        self.journal, self.handles, self.sigma, self.warned = journal, handles, sigma, False

    def __call__(self, t: int) -> None:
        made = [r for r in self.journal.records if r["iteration"] == t]
        if self.warned or not made or not all(r.get("valid") is False for r in made):
            return
        self.warned = True
        log.warning("iteration %d: all %d candidates were implausible (self-intersecting or folded), none "
                    "simulated: %d handles at budget.sigma=%g fold the object. Lower budget.sigma, cap the "
                    "displacement (budget.tau) or use fewer handles (selector=heuristic); python -m grt.select "
                    "object=... selector=... 'probe.sigmas=[...]' counts the candidates each sigma folds",
                    t, len(made), self.handles, self.sigma)


def _confirm(cfg: DictConfig, run_dir: Path, result, deformer: ShapeDeformer, evaluator, seeds: list[int],
             score: ScoreSpec) -> dict | None:
    """Re-score the nominal object and the CrashShapes on fresh episodes (``budget.confirm_trials`` > 0)."""
    trials = int(cfg.budget.confirm_trials)
    best = crash_records(result.records, cfg.budget.top_k, result.s0, crash_margin(cfg.task))  # CrashShapes only
    if trials and not best:
        log.info("confirm: no CrashShape to re-score on fresh episodes (budget.confirm_trials=%d)", trials)
    if trials == 0 or not best:
        return None
    meshes = deformer.meshes(np.asarray([r["theta"] for r in best]))
    if hasattr(evaluator, "start"):
        evaluator.start()  # a resume that only confirms starts its workers here (says so; silent if up)
    with progress(1 + len(best), f"confirm ({trials} fresh episodes)", "shape") as bar:
        return confirm(run_dir, best, meshes, deformer.mesh, evaluator, seeds, cfg.budget.seed, trials,
                       ci=score.ci, on_evaluated=lambda: bar.update(1))


def _select_handles(cfg: DictConfig, mesh, run_dir: Path, selector) -> HandleSet:
    """Handles and anchors: from the run folder when resuming, else from the configured selector."""
    path = run_dir / "handles.json"
    if path.exists():
        return HandleSet.from_json(path.read_text())
    handle_set = selector.select(mesh, task_description(cfg.task))
    write_text_atomic(path, handle_set.to_json())  # a kill mid-write must not leave a half file to resume from
    return handle_set


def _announce_deformer(deformer: ShapeDeformer) -> None:
    """Say what the deformation model does to the selected anchors (the smooth method releases some)."""
    core = deformer.core
    if core.method != "smooth":
        return
    radius_mm = core.region_radius * deformer.meters_per_unit * 1000
    log.info("deformer: smooth handles, each moves a region of radius %.3g of the diagonal (%.1f mm)",
             core.radius, radius_mm)
    if len(core.released_anchors):
        some = core.released_anchors.tolist()
        listed = ", ".join(map(str, some[:5])) + (", ..." if len(some) > 5 else "")  # all: summary.json
        log.info("deformer: released %d point anchors inside handle regions (they would pin dimples): %s; "
                 "%d anchors hold the shape", len(some), listed, len(core.anchors))


def _progress(bar, rec: dict, score: ScoreSpec) -> None:
    bar.update(1)
    bar.set_postfix(it=rec["iteration"], score=score.fmt(rec["score"], unit=True))
