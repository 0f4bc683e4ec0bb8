"""``python -m grt.run``: red-team a policy on a task and object; Hydra entry point.

Examples::

    python -m grt.run                                   # grasp task, default object, budget=quick
    python -m grt.run object=bottle selector=all optimizer=cma_es budget=paper
    python -m grt.run -m selector=heuristic,all optimizer=topdm,gaussian budget=smoke
    python -m grt.run resume=outputs/grasp/mug/heuristic-topdm/2026-11-23_01-00-00

``main`` resolves the config once and calls :func:`run`, a plain function tests import; it returns
the run's Final Drop so Hydra sweepers can optimize it.

A run writes its own config once, when it starts, to ``run_config.yaml`` (read-only), and ``resume=DIR``
alone is the whole command to continue it. :func:`resume_overrides` checks DIR and the command before
Hydra starts, so a refused resume writes nothing anywhere, and hands Hydra the run's own overrides;
``main`` then runs the saved config. With ``resume=`` only the :data:`RESUME_FREE` keys may be given
(they do not change the search); any other key must keep the run's own value. Ctrl-C ends a run with
one line naming the command that continues it (exit code 130).
"""

from __future__ import annotations

import logging
import math
import os
import shlex
import sys
import time
import traceback
from dataclasses import dataclass
from pathlib import Path

import hydra
import numpy as np
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from hydra.errors import HydraException
from hydra.types import RunMode
from hydra.utils import instantiate
from omegaconf import DictConfig, ListConfig, OmegaConf
from tqdm.auto import tqdm

from grt.config import (  # also registers schemas and resolvers before composition
    RUN_CONFIG,
    is_run_folder,
    validate,
)
from grt.errors import exit_on_user_error, find_user_error, run_cli
from grt.geometry.deform import ShapeDeformer, deformer_options
from grt.geometry.mesh import check_object_size, load_mesh
from grt.geometry.prepare import MeshSettings
from grt.geometry.prepare import describe as describe_preparation
from grt.geometry.quality import candidate_validity
from grt.journal import Journal, JournalError
from grt.outputs import print_summary, save_nominal, write_outputs, write_text_atomic
from grt.redteam import RedTeamLoop, episode_seeds
from grt.scores import ScoreSpec, check_nominal_floor, nominal_floor
from grt.selectors.base import HandleSet
from grt.tasks import preflight

log = logging.getLogger("grt.run")

# Keys a resume may set (with what is under them): none changes the search (results are identical with any
# number of workers; loggers, the collision cache and Hydra's own files only record; the nominal floor only
# decides whether the run goes on after S0), so a resumed run stays the run its journal was written by.
RESUME_FREE = ("budget.workers", "evaluator.workers", "logger", "paths.cache_dir", "hydra", "task.nominal_floor",
               "budget.confirm_trials")
# The parts of a resumed run's config taken from the command; all the rest is the run's saved config.
FROM_COMMAND = ("budget.workers", "evaluator.workers", "evaluator.cache_dir", "logger", "paths",
                "task.nominal_floor", "budget.confirm_trials")
# FROM_COMMAND keys set even where the run's saved config lacks them (a run from before the key existed).
ADDED_KEYS = ("task.nominal_floor", "budget.confirm_trials")
RUN_FOLDERS = "outputs/<task>/<object>/<selector>-<optimizer>/<time>"
INTERRUPTED = 130  # the shell's code for a process ended by SIGINT
_ABSENT = object()


class ResumeError(JournalError):
    """``resume=`` of a folder that is not a run, or with settings that would change the run."""


def run(cfg: DictConfig) -> dict:
    """Run (or resume) one red-team run; returns its summary (also written to ``summary.json``)."""
    run_dir = Path(cfg.resume or cfg.paths.output_dir)
    if cfg.resume:
        _refuse_unless_run(run_dir)
    score = ScoreSpec.from_task(cfg.task)  # a bad task.ci fails here, before any simulation
    floor = nominal_floor(cfg.task)
    run_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    scale = cfg.get("object_scale", 1.0)  # absent in runs from before the key: meters
    mesh = load_mesh(cfg.object, scale=scale, settings=MeshSettings.from_config(cfg.get("mesh")))
    check_object_size(mesh)  # a mesh in millimetres: refused before any file
    print("\n".join(describe_preparation(mesh)), flush=True)  # every repair and the fidelity figures
    preflight(_plain(cfg.task), instantiate(cfg.policy), mesh, scale)  # wrong plug/checkpoint: likewise
    save_run_config(cfg, run_dir)
    handle_set = _select_handles(cfg, mesh, run_dir)
    save_nominal(run_dir, mesh)  # the mesh every CrashShape deforms (its vertex order, meters)
    deformer = ShapeDeformer(mesh, handle_set.handles, handle_set.anchors, **deformer_options(cfg.deformer))
    _announce_deformer(deformer)
    optimizer = instantiate(cfg.optimizer)(num_handles=len(handle_set.handles))
    seeds = episode_seeds(cfg.budget.seed, cfg.budget.trials)
    journal = Journal(run_dir / "journal.jsonl")
    if journal.recovered_truncated_line:
        log.warning("journal: ignored a truncated last line (an interrupted write)")
    if len(journal):
        log.info("resuming %s: %d candidates already in the journal", run_dir, len(journal))
    logger = instantiate(cfg.logger)
    evaluator = instantiate(cfg.evaluator)(task=_plain(cfg.task), policy=_plain(cfg.policy), nominal=mesh,
                                           progress=False)  # the red-team bar shows progress
    total = 1 + cfg.budget.population * cfg.budget.iterations
    folding = FoldingWatch(journal, len(handle_set.handles), cfg.budget.sigma)
    bar = tqdm(total=total, desc="red-team", unit="cand", initial=len(journal), dynamic_ncols=True)
    try:
        logger.start(run_dir, name=run_dir.name, config=_plain(cfg))
        loop = RedTeamLoop(
            deformer, optimizer, evaluator, journal, seeds, cfg.budget.iterations, tau=cfg.budget.tau,
            complexity=_entropy,
            on_candidate=lambda rec: _progress(bar, rec, score),
            on_iteration=lambda t, scores: (
                logger.log_iteration(t, {"best_score": optimizer.best_score, "mean_score": float(np.mean(scores))}),
                folding(t)),
            ci=score.ci, on_nominal=lambda s0: check_nominal_floor(s0, floor, score, shlex.quote(str(run_dir))),
            validity=candidate_validity if cfg.deformer.get("validity", False) else None)
        result = loop.run()
        bar.close()
        confirmation = _confirm(cfg, run_dir, result, deformer, evaluator, seeds, score)
        summary = write_outputs(cfg, run_dir, result, deformer, handle_set, evaluator,
                                wall_s=time.perf_counter() - start, confirmation=confirmation)
        logger.log_summary(summary)
        logger.log_images({"curve": run_dir / "curve.png", "shapes": run_dir / "shapes.png"})
    finally:
        bar.close()
        evaluator.close()
        logger.finish()
    print_summary(summary, run_dir)
    return summary


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
    from grt.confirm import confirm
    from grt.outputs import crash_records

    trials = int(cfg.budget.get("confirm_trials", 0) or 0)
    best = crash_records(result.records, cfg.budget.top_k)
    if trials == 0 or not best:
        return None
    meshes = deformer.meshes(np.asarray([r["theta"] for r in best]))
    with tqdm(total=1 + len(best), desc=f"confirm ({trials} fresh episodes)", unit="shape",
              dynamic_ncols=True) as bar:
        return confirm(run_dir, best, meshes, deformer.mesh, evaluator, seeds, cfg.budget.seed, trials,
                       ci=score.ci, on_evaluated=lambda: bar.update(1))


def _select_handles(cfg: DictConfig, mesh, run_dir: Path) -> HandleSet:
    """Handles and anchors: from the run folder when resuming, else from the configured selector."""
    path = run_dir / "handles.json"
    if path.exists():
        return HandleSet.from_json(path.read_text())
    selector = instantiate(cfg.selector)
    handle_set = selector.select(mesh, cfg.task.description)
    write_text_atomic(path, handle_set.to_json())  # a kill mid-write must not leave a half file to resume from
    return handle_set


def _entropy(mesh) -> float:
    from grt.geometry.complexity import angular_deficit_entropy

    return angular_deficit_entropy(mesh)


def _announce_deformer(deformer: ShapeDeformer) -> None:
    """Say what the deformation model does to the selected anchors (the smooth method releases some)."""
    core = deformer.core
    if core.method != "smooth":
        return
    radius_mm = core.region_radius * deformer.meters_per_unit * 1000
    log.info("deformer: smooth handles, each moves a region of radius %.3g of the diagonal (%.1f mm)",
             core.radius, radius_mm)
    if len(core.released_anchors):
        log.info("deformer: released %d point anchors inside handle regions (they would pin dimples): %s; "
                 "%d anchors hold the shape", len(core.released_anchors), core.released_anchors.tolist(),
                 len(core.anchors))


def _progress(bar: tqdm, rec: dict, score: ScoreSpec) -> None:
    bar.update(1)
    bar.set_postfix(it=rec["iteration"], score=score.fmt(rec["score"], unit=True))


def _plain(node) -> dict:
    return OmegaConf.to_container(node, resolve=True)


def save_run_config(cfg: DictConfig, run_dir: Path) -> None:
    """Write the run's own record once, read-only: what ``resume=`` reads, so no later command rewrites it.

    ``overrides`` and ``choices`` are its command line and config-group options (Hydra's; empty when
    :func:`run` is called without Hydra), ``config`` its resolved config.
    """
    path = run_dir / RUN_CONFIG
    if path.exists():
        return
    hydra_cfg = HydraConfig.get() if HydraConfig.initialized() else None
    record = {
        "overrides": [o for o in hydra_cfg.overrides.task if _key(o) != "resume"] if hydra_cfg else [],
        "choices": {k: v for k, v in _plain(hydra_cfg.runtime.choices).items() if not _under(k, ("hydra",))}
        if hydra_cfg else {},
        "config": {**_plain(cfg), "resume": None},
    }
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(f"# {RUN_CONFIG}: this run as it started (written once by grt.run). Continue it with\n"
                   f"# python -m grt.run resume=<this folder>\n" + OmegaConf.to_yaml(record))
    os.replace(tmp, path)
    path.chmod(0o444)


@dataclass
class SavedRun:
    """A run's own start, as its folder records it.

    Attributes:
        overrides: its command line's overrides (``resume=``, ``hydra.*`` and ``paths.output_dir`` left out).
        choices: its config-group options, e.g. ``{"selector": "all"}``.
        config: its config (resolved; Hydra's record for a run from before ``run_config.yaml``).
    """

    overrides: list[str]
    choices: dict
    config: DictConfig

    @classmethod
    def load(cls, run_dir: Path) -> SavedRun:
        """Read ``run_dir``; a missing folder or one that is not a run raises :class:`ResumeError`."""
        _refuse_unless_run(run_dir)
        try:
            if (run_dir / RUN_CONFIG).is_file():
                record = OmegaConf.load(run_dir / RUN_CONFIG)
                overrides, choices, config = record.overrides, record.choices, record.config
            else:  # a run from before run_config.yaml: Hydra's files (right unless an old resume rewrote them)
                hydra_dir = run_dir / ".hydra"
                config = OmegaConf.load(hydra_dir / "config.yaml")
                overrides = OmegaConf.load(hydra_dir / "overrides.yaml")
                choices = OmegaConf.load(hydra_dir / "hydra.yaml").hydra.runtime.choices
            overrides, choices = OmegaConf.to_container(overrides), OmegaConf.to_container(choices)
        except Exception as exc:  # noqa: BLE001 - any unreadable record is the same user error
            raise ResumeError(f"resume={run_dir}: its record of the run cannot be read ({exc}); "
                              "start a new run") from None
        own = [o for o in overrides if not _under(_key(o), ("resume", "hydra", "paths.output_dir"))]
        return cls(own, {k: v for k, v in choices.items() if not _under(k, ("hydra",))}, config)

    def value(self, key: str):
        """The run's option of group ``key``, or its value of config key ``key`` (``_ABSENT``: none)."""
        if key in self.choices:
            return self.choices[key]
        value = OmegaConf.select(self.config, key, default=_ABSENT, throw_on_resolution_failure=False)
        return OmegaConf.to_container(value) if isinstance(value, (DictConfig, ListConfig)) else value

    def keeps(self, override: Override) -> bool:
        """Whether ``override`` gives the run's own value (so it changes nothing)."""
        if override.is_sweep_override():
            return False
        have = self.value(override.key_or_group)
        if override.is_delete():
            return have is _ABSENT
        return have is not _ABSENT and have == override.value()


def resume_overrides(overrides: list[str]) -> list[str]:
    """The overrides Hydra gets for a command with ``resume=DIR``: the run's own ones.

    Called before Hydra starts, so a refused resume writes nothing. The other overrides given must be
    :data:`RESUME_FREE` keys or give the run's own values; the free ones are passed on, and Hydra writes
    its files of a resume under ``DIR/.hydra/resume`` (``DIR/.hydra`` stays the record of the start).

    Returns:
        ``overrides`` unchanged without ``resume=``.

    Raises:
        ResumeError: DIR is missing or not a run, or an override would change the run (names the keys).
    """
    try:
        given = OverridesParser.create().parse_overrides(overrides)
    except HydraException:
        return overrides  # Hydra reports a malformed override itself
    resume = [o for o in given if o.key_or_group == "resume"]
    if not resume or not resume[-1].value():
        return overrides
    run_dir = resume[-1].value()
    if not isinstance(run_dir, str):
        raise ResumeError(f"{resume[-1].input_line}: resume= takes one run folder")
    saved = SavedRun.load(Path(run_dir))
    free = [o for o in given if _under(o.key_or_group, RESUME_FREE)]
    changed = [o for o in given if o.key_or_group != "resume" and o not in free and not saved.keeps(o)]
    if changed:
        what = ", ".join(f"{o.key_or_group} (the run's: {_shown_value(saved.value(o.key_or_group))}, "
                         f"given: {o.input_line.partition('=')[2] or 'deleted'})" for o in changed)
        raise ResumeError(
            f"resume={run_dir}: {what} would change the run, which keeps its own config ({RUN_CONFIG} there). "
            f"Continue it with resume={run_dir} alone (allowed with it: {', '.join(RESUME_FREE)}.*), "
            "or start a new run with these settings: the same command without resume=")
    own = [line for line in saved.overrides if not any(_under(_key(line), (o.key_or_group,)) for o in free)]
    return [*own, "hydra.output_subdir=.hydra/resume", *(o.input_line for o in free), resume[-1].input_line]


def own_config(cfg: DictConfig) -> DictConfig:
    """A resumed run's config: its saved one, with the :data:`FROM_COMMAND` parts of this command."""
    path = Path(cfg.resume) / RUN_CONFIG
    if not path.is_file():
        return cfg  # a run from before run_config.yaml: composed from its own .hydra/overrides.yaml
    own = OmegaConf.create(OmegaConf.to_container(OmegaConf.load(path).config))
    for key in FROM_COMMAND:
        value = OmegaConf.select(cfg, key, default=_ABSENT)
        if value is not _ABSENT and (key in ADDED_KEYS or OmegaConf.select(own, key, default=_ABSENT) is not _ABSENT):
            OmegaConf.update(own, key, _plain(value) if isinstance(value, DictConfig) else value, merge=False)
    own.resume = cfg.resume
    return own


def interrupted(run_dir: Path) -> str:
    """The line printed on Ctrl-C: how to continue the run (or that nothing of it was saved yet)."""
    if not is_run_folder(run_dir):
        return "interrupted (Ctrl-C) before the run saved its config; start it again with the same command"
    shown = Path(os.path.relpath(run_dir)) if run_dir.resolve().is_relative_to(Path.cwd()) else run_dir
    return f"interrupted (Ctrl-C); continue this run with: python -m grt.run resume={shlex.quote(str(shown))}"


def _refuse_unless_run(run_dir: Path) -> None:
    if not run_dir.is_dir():
        why = "no such folder"
    elif not is_run_folder(run_dir):
        why = f"not a GRT run folder (no {RUN_CONFIG})"
    else:
        return
    raise ResumeError(f"resume={run_dir}: {why}, so nothing to resume. Give the folder of an earlier run "
                      f"({RUN_FOLDERS}).")


def _key(override: str) -> str:
    return OverridesParser.create().parse_override(override).key_or_group


def _under(key: str, prefixes: tuple[str, ...]) -> bool:
    """Whether ``key`` is one of ``prefixes`` or lies under one (``logger.mode``, ``hydra/launcher``)."""
    return any(key == p or key.startswith((f"{p}.", f"{p}/")) for p in prefixes)


def _shown_value(value) -> str:
    return "unset" if value is _ABSENT else str(value)


@hydra.main(config_path="../conf", config_name="run", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns Final Drop (NaN for a failed job of a sweep, which goes on)."""
    if cfg.resume:
        cfg = own_config(cfg)
    try:
        validate(cfg)  # budget ranges, +budget keys, optimizer settings: refused before any simulation
        summary = run(cfg)
    except KeyboardInterrupt:
        log.warning(interrupted(Path(cfg.resume or cfg.paths.output_dir)))
        raise SystemExit(INTERRUPTED) from None
    except Exception as exc:
        if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
            out = Path(cfg.paths.output_dir)  # the job's own folder (never a refused resume's)
            out.mkdir(parents=True, exist_ok=True)
            (out / "error.txt").write_text(traceback.format_exc())
            log.error("job failed (%s: %s); details in %s; the sweep goes on",
                      type(exc).__name__, exc, out / "error.txt")
            return math.nan
        found = find_user_error(exc)
        if found is not None:
            log.error("%s: %s", type(found).__name__, found)
            raise SystemExit(2) from exc
        raise
    return float(summary["final_drop"])


def cli(argv: list[str] | None = None) -> None:
    """``python -m grt.run``: a ``resume=`` is checked, and becomes the run's own command, before Hydra starts."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if any("resume=" in arg for arg in argv):
        from hydra._internal.utils import get_args_parser  # the parser hydra.main itself uses on sys.argv

        overrides = get_args_parser().parse_args(argv).overrides
        with exit_on_user_error():
            new = resume_overrides(overrides)
        sys.argv[1:] = [*(arg for arg in argv if arg not in overrides), *new]
    run_cli(main)


if __name__ == "__main__":
    cli()
