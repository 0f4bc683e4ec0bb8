"""One red-team run as a plain function: ``run(cfg) -> summary``, which the ``grt-run`` app and tests call.

:func:`run` parses the settings once into a :class:`grt.plan.RunPlan` (:func:`grt.config.make_plan`), locks
the run folder and calls :func:`red_team`, the paper's flow in named steps: the nominal object
(:func:`prepare_object`), the run's classes (:func:`build_parts`), its record (:mod:`grt.runfolder.record`), the
handles (:func:`select_handles`), the deformation model (:func:`make_deformer`), the search
(:func:`search`, Algorithm 1 in :class:`grt.redteam.RedTeamLoop`), the confirmation of its CrashShapes on
fresh episodes (:func:`confirm_shapes`, ``budget.confirm_trials`` > 0), the shrink of the confirmed ones to
their smallest confirmed scale (:func:`shrink_shapes`, ``budget.shrink``) and the outputs (:mod:`grt.outputs`,
:func:`report`). The command line (Hydra, ``resume=``, Ctrl-C, sweeps) is :mod:`grt.cli.run`'s.
"""

from __future__ import annotations

import contextlib
import json
import logging
import shlex
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from grt.config import make_plan
from grt.confirm import confirm
from grt.console import progress
from grt.evaluators.base import NothingScoredError, evaluator_preflight
from grt.fileio import write_text_atomic
from grt.geometry.complexity import angular_deficit_entropy
from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import check_object_size, load_mesh, mesh_hash
from grt.geometry.prepare import describe as describe_preparation
from grt.journal import Journal
from grt.outputs import crash_records, print_summary, save_nominal, write_outputs
from grt.plan import RunPlan, dotted
from grt.policies.base import PolicyServerError
from grt.redteam import RedTeamLoop, RedTeamResult, episode_seeds
from grt.report import figures
from grt.runfolder.lock import locked
from grt.runfolder.record import (
    RUN_CONFIG,
    ResumeError,
    load_run_config,
    refuse_unless_run,
    resume_command,
    save_run_config,
)
from grt.scores import ScoreSpec, check_nominal_floor
from grt.selectors.base import HandleSet
from grt.shrink import ShrinkSettings, ShrinkShape, shrink, shrink_seeds
from grt.swapcheck import check_settings, swap_check
from grt.targets import build
from grt.tasks import check_fit, preflight, task_description, task_object

log = logging.getLogger("grt.run")


def run(cfg) -> dict:
    """Run (or resume) one red-team run; returns its summary (also written to ``summary.json``).

    Args:
        cfg: the run's plan (:class:`grt.plan.RunPlan`), or its config (composed by Hydra, or a run folder's
            own), which :func:`grt.config.make_plan` parses once (a bad task score setting fails here, before
            any simulation).

    A resume of a finished run with nothing left to do (:func:`nothing_to_do`) says so and returns the run's
    summary, changing nothing.
    """
    plan = cfg if isinstance(cfg, RunPlan) else make_plan(cfg)
    if plan.resume:
        refuse_unless_run(plan.run_dir)
        line = nothing_to_do(plan.run_dir, plan)
        if line is not None:
            print(line, flush=True)
            return json.loads((plan.run_dir / "summary.json").read_text())
    plan.run_dir.mkdir(parents=True, exist_ok=True)
    with locked(plan.run_dir):  # one process per run folder (grt.run's callback took it before Hydra wrote there)
        return red_team(plan)


def red_team(plan: RunPlan) -> dict:
    """The run in ``plan.run_dir``, as the paper's flow: the nominal object, handles, the deformation model,
    the search (Algorithm 1), the confirmation of its CrashShapes on fresh episodes, their shrink, the outputs."""
    start = time.perf_counter()
    mesh = prepare_object(plan)  # refused (too big, another task's, an edited record) before any file
    parts = build_parts(plan, mesh)  # a class that cannot be built is one line and leaves no folder
    journal = Journal(plan.run_dir / "journal.jsonl")
    with parts:
        if len(journal) < plan.budget.candidates:
            parts.start()  # one line, then the workers' start-up, outside the bar's rate and ETA
        seeds = episode_seeds(plan.budget.seed, plan.budget.trials)  # every candidate on the same episodes
        swap, nominal = check_swap(plan, mesh, parts.evaluator, journal, seeds)  # a disagreeing copy: no record
        save_run_config(plan)  # the run's own record, what resume= continues
        handle_set = select_handles(plan, mesh, parts.selector)
        deformer = make_deformer(plan, mesh, handle_set)
        optimizer = build(plan.optimizer, "optimizer", num_handles=len(handle_set.handles))
        with resumable(plan.run_dir):
            result = search(plan, deformer, optimizer, parts, journal, seeds, nominal)
            confirmation = confirm_shapes(plan, result, deformer, parts.evaluator, seeds)
            shrunk = shrink_shapes(plan, result, deformer, parts.evaluator, confirmation, seeds)
        summary = write_outputs(plan, result, deformer, handle_set, parts.evaluator,
                                wall_s=time.perf_counter() - start, confirmation=confirmation, shrink=shrunk,
                                swap_check=swap)
        report(plan, summary, parts.logger)
    print_summary(summary, plan.run_dir)
    return summary


def prepare_object(plan: RunPlan) -> trimesh.Trimesh:
    """The nominal object as the run deforms it (meters), checked before anything is written: its size, a
    resume's object against the run's own, and the task and policy it is for; every repair is printed."""
    check_fit(plan.task, plan.policy)  # no Vulkan, a policy of another kind: before the object is prepared
    mesh = load_mesh(task_object(plan.task, plan.object, plan.cache_dir), scale=plan.object_scale,
                     settings=plan.mesh)
    check_object_size(mesh)  # a mesh in millimetres
    if plan.resume:
        check_same_object(plan.run_dir, mesh, plan)  # an edited record
    print("\n".join(describe_preparation(mesh)), flush=True)  # every repair and the fidelity figures
    preflight(plan.task, plan.policy, mesh, plan.object_scale)  # wrong plug, policy kind or checkpoint
    evaluator_preflight(plan.evaluator, plan.task, plan.policy)  # evaluator=gpu without CUDA, ...
    check_settings(plan.task, plan.object, plan.swap_check)  # an override with nothing to override
    return mesh


def check_swap(plan: RunPlan, mesh: trimesh.Trimesh, evaluator, journal: Journal,
               seeds: list[int]) -> tuple[dict, object | None]:
    """The swap check of a ManiSkill task (:func:`grt.swapcheck.swap_check`) on the nominal's seeds, before the
    run's record is saved: a disagreeing copy stops the run with nothing written. Returns the check's record
    and the nominal's result when the check scored it (the search journals it instead of scoring it again)."""
    swap, nominal = swap_check(plan.task, plan.policy, plan.object, mesh, seeds, evaluator, plan.swap_check,
                               plan.cache_dir, plan.evaluator, journal.get(0, 0))
    if swap["stock"] is not None:  # (a task without a stock env: said in the summary)
        print(figures.swap_line({"swap_check": swap}), flush=True)
    return swap, nominal


@dataclass
class RunParts:
    """The classes a run builds from its settings (the user's among them): the selector (``None`` when the
    run folder has its handles), the logger and the evaluator; leaving the block closes them."""

    selector: object | None
    logger: object
    evaluator: object

    def start(self) -> None:
        """Start the evaluator's workers (an evaluator without workers has nothing to start)."""
        if hasattr(self.evaluator, "start"):
            self.evaluator.start()

    def __enter__(self) -> RunParts:
        return self

    def __exit__(self, *exc) -> None:
        self.evaluator.close()
        self.logger.finish()


def build_parts(plan: RunPlan, mesh: trimesh.Trimesh) -> RunParts:
    """Build the run's selector, logger and evaluator before its record is saved (:func:`grt.targets.build`);
    the workers build the task's session as they start."""
    selector = None if (plan.run_dir / "handles.json").exists() else build(plan.selector, "selector")
    logger = build(plan.logger, "logger")
    evaluator = build(plan.evaluator, "evaluator", task=plan.task, policy=plan.policy, nominal=mesh,
                      progress=False)  # the red-team bar shows progress
    return RunParts(selector, logger, evaluator)


def select_handles(plan: RunPlan, mesh: trimesh.Trimesh, selector) -> HandleSet:
    """Handles and anchors: from the run folder when resuming, else from the configured selector."""
    path = plan.run_dir / "handles.json"
    if path.exists():
        return HandleSet.from_json(path.read_text())
    handle_set = selector.select(mesh, task_description(plan.task))
    write_text_atomic(path, handle_set.to_json())  # a kill mid-write must not leave a half file to resume from
    return handle_set


def make_deformer(plan: RunPlan, mesh: trimesh.Trimesh, handle_set: HandleSet) -> ShapeDeformer:
    """The deformation model of the run (``nominal.obj`` saved first: the mesh every CrashShape deforms, its
    vertex order, in meters; a resume's is the same mesh, :func:`check_same_object`)."""
    if not (plan.run_dir / "nominal.obj").is_file():
        save_nominal(plan.run_dir, mesh)
    deformer = ShapeDeformer(mesh, handle_set.handles, handle_set.anchors, **plan.deformer.options)
    _announce_deformer(deformer)
    return deformer


def search(plan: RunPlan, deformer: ShapeDeformer, optimizer, parts: RunParts, journal: Journal,
           seeds: list[int], nominal=None) -> RedTeamResult:
    """Algorithm 1 (:class:`grt.redteam.RedTeamLoop`) with the run's progress bar, logger and warnings; a
    resume replays the journal's candidates. ``nominal``: the nominal's result already scored on ``seeds``
    (the swap check's), journaled instead of scored again."""
    tau, how = plan.smoothness_cap(deformer.mesh)
    print(f"Smoothness-Score cap: {how}", flush=True)
    if journal.recovered_truncated_line:
        log.warning("journal: ignored a truncated last line (an interrupted write)")
    if len(journal):
        log.info("resuming %s: %d candidates already in the journal", plan.run_dir, len(journal))
    folding, logger, score = FoldingWatch(journal, deformer.core.num_handles, plan.budget.sigma), parts.logger, \
        plan.score
    logger.start(plan.run_dir, name=plan.run_dir.name, config=plan.config)
    with progress(plan.budget.candidates, "red-team", "cand", initial=len(journal)) as bar:
        return RedTeamLoop(
            deformer, optimizer, parts.evaluator, journal, seeds, plan.budget.iterations, tau=tau,
            complexity=angular_deficit_entropy, on_candidate=lambda rec: _progress(bar, rec, score),
            on_iteration=lambda t, scores: (
                logger.log_iteration(t, {"best_score": optimizer.best_score, "mean_score": float(np.mean(scores))}),
                folding(t)),
            ci=score.ci, validity=plan.deformer.check, racing=plan.racing(), size_penalty=plan.budget.size_penalty,
            size_scale=tau or 0.087 * float(np.linalg.norm(deformer.mesh.extents)), nominal=nominal,
            on_nominal=lambda s0: check_nominal_floor(s0, plan.nominal_floor, score, resume_command(plan.run_dir)),
        ).run()


@contextlib.contextmanager
def resumable(run_dir: Path) -> Iterator[None]:
    """Name the command that continues the run in the errors a user can fix while it runs (a served policy
    that went away, a policy whose output the task cannot use): the journal keeps what finished."""
    try:
        yield
    except PolicyServerError as err:
        raise PolicyServerError(f"{err}; start the server again and finish the run: {resume_command(run_dir)}") \
            from None
    except NothingScoredError as err:
        raise NothingScoredError(f"{err}; fix that, then continue the run with: {resume_command(run_dir)}") from None


def confirm_shapes(plan: RunPlan, result: RedTeamResult, deformer: ShapeDeformer, evaluator,
                   seeds: list[int]) -> dict | None:
    """Re-score the nominal object and the CrashShapes on fresh episodes (``budget.confirm_trials`` > 0,
    :func:`grt.confirm.confirm`); ``None`` when off or there is no CrashShape."""
    trials = plan.budget.confirm_trials
    best = crash_records(result.records, plan.budget.top_k, result.s0, plan.crash_margin)  # CrashShapes only
    if trials and not best:
        log.info("confirm: no CrashShape to re-score on fresh episodes (budget.confirm_trials=%d)", trials)
    if trials == 0 or not best:
        return None
    meshes = deformer.meshes(np.asarray([r["theta"] for r in best]))
    if hasattr(evaluator, "start"):
        evaluator.start()  # a resume that only confirms starts its workers here (says so; silent if up)
    with progress(1 + len(best), f"confirm ({trials} fresh episodes)", "shape") as bar:
        return confirm(plan.run_dir, best, meshes, deformer.mesh, evaluator, seeds, plan.budget.seed, trials,
                       ci=plan.score.ci, on_evaluated=lambda: bar.update(1))


def shrink_settings(plan: RunPlan) -> ShrinkSettings | None:
    """The run's shrink settings (``budget.shrink``; ``None``: off, or no confirmation to build on)."""
    b = plan.budget
    return ShrinkSettings(b.shrink_ratio, b.shrink_min_alpha, b.shrink_rounds) if b.shrink and b.confirm_trials \
        else None


def shrink_shapes(plan: RunPlan, result: RedTeamResult, deformer: ShapeDeformer, evaluator,
                  confirmation: dict | None, seeds: list[int]) -> dict | None:
    """Shrink each confirmed CrashShape on fresh episodes of its own (:func:`grt.shrink.shrink`); ``None`` when
    off or none was confirmed."""
    settings = shrink_settings(plan)
    confirmed = [c for c in (confirmation or {}).get("shapes", []) if c["confirmed"]]
    if settings is None or not confirmed:
        return None
    thetas = {(r["iteration"], r["candidate"]): r["theta"] for r in result.records}
    shapes = [ShrinkShape(c["rank"], c["iteration"], c["candidate"], np.asarray(thetas[c["iteration"], c["candidate"]]),
                          c["score"], tuple(c["ci95"]), confirmation["trials"]) for c in confirmed]
    fresh = shrink_seeds(plan.budget.seed, confirmation["trials"], seeds, confirmation["seeds"])
    levels = 1 + len(shapes) * len(settings.ladder())
    start = time.perf_counter()
    with progress(levels, f"shrink (nominal, then up to {levels - 1} levels of {len(shapes)} CrashShapes)",
                  "level") as bar:
        out = shrink(plan.run_dir, shapes, deformer, evaluator, fresh, settings, binary=plan.score.binary,
                     ci=plan.score.ci, validity=plan.deformer.check, on_level=lambda: bar.update(1))
    out["wall_s"] = round(time.perf_counter() - start, 1)  # this session's (a resume replays the journal)
    log.info("shrink: %d simulated trials over %d levels", out["trials_used"],
             sum(s["levels_tested"] for s in out["shapes"]))
    return out


def report(plan: RunPlan, summary: dict, logger) -> None:
    """Give the logger the summary and pictures, then film the CrashShapes and write ``report.html``
    (:func:`write_report`)."""
    logger.log_summary(summary)
    logger.log_images({"curve": plan.run_dir / "curve.png", "shapes": plan.run_dir / "shapes.png"})
    write_report(plan, summary, logger)


# Settings that make something after the search (a report's videos, a logger's record): given other values
# than the run had, a resume of a finished run has that to do.
AFTER_SEARCH = ("report", "budget.videos", "logger")


def nothing_to_do(run_dir: Path, plan: RunPlan) -> str | None:
    """The line a resume of a finished run prints when ``plan`` (its config as this command resolved it) asks
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
    if len(records) < plan.budget.candidates or any(dotted(plan.config, k) != dotted(saved, k) for k in AFTER_SEARCH):
        return None
    trials = plan.budget.confirm_trials
    if trials and (summary.get("confirm") or {}).get("trials") != trials:
        nominal = next((r for r in records if r["iteration"] == 0), None)
        if nominal is None or crash_records(records, plan.budget.top_k, nominal["score"], plan.crash_margin):
            return None
    settings = shrink_settings(plan)
    confirmed = any(c.get("confirmed") for c in (summary.get("confirm") or {}).get("shapes", []))
    if settings is not None and confirmed and not _same_shrink(summary.get("shrink"), settings):
        return None
    return (f"nothing to do: {run_dir} is a finished run ({len(records)} candidates in its journal, summary.json "
            f"written); nothing was changed. Its table: python -m grt.report {shlex.quote(str(run_dir))}; more "
            f"episodes for its CrashShapes: {resume_command(run_dir)} budget.confirm_trials=N")


def _same_shrink(block: dict | None, settings: ShrinkSettings) -> bool:
    """Whether a summary's ``shrink`` block was made with ``settings``."""
    return block is not None and all(block.get(k) == v for k, v in settings.fields().items())


def check_same_object(run_dir: Path, mesh, plan: RunPlan) -> None:
    """Refuse a resume whose object (``plan.object`` as loaded: ``mesh``) is not the one the run was made with
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
        raise ResumeError(f"resume={run_dir}: the object its record gives (object={plan.object}, object_scale="
                          f"{plan.object_scale}, mesh settings) is not the object the run was made with (its "
                          f"nominal.obj and journal): its record ({RUN_CONFIG}) was edited. A run keeps the "
                          f"config it started with: restore {RUN_CONFIG}, or start a new run with this object "
                          "(the same command without resume=)")


def write_report(plan: RunPlan, summary: dict, logger=None) -> None:
    """Film the top CrashShapes' failing trials (``report.videos``; rendering only here, after the search)
    and write ``report.html``. A report that fails is one warning: the run's results are already written."""
    from grt.report.html import write_run_report
    from grt.rerun import render_videos

    start, run_dir, count = time.perf_counter(), plan.run_dir, plan.report_videos
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
