"""Run folders: the one module that writes, reads, validates, resumes and migrates them.

A red-team run writes its own record once, when it starts, to ``run_config.yaml`` (read-only)::

    grt_format: 2          # the folder's format (absent: format 1)
    overrides: [...]       # its command line (Hydra's; resume=, hydra.* and paths.output_dir left out)
    choices: {...}         # its config-group options
    config: {...}          # its resolved config

and ``resume=DIR`` alone is the whole command to continue it. :func:`resume_overrides` checks DIR and the
command before Hydra starts, so a refused resume writes nothing anywhere, and hands Hydra the run's own
overrides; :func:`own_config` then gives the app the saved config. With ``resume=`` only the
:data:`RESUME_FREE` keys may be given (they do not change the search); any other key must keep the run's
own value. A training folder (``python -m grt.train``) is resumed the same way (:data:`TRAINING`): its
record is Hydra's of its start, ``.hydra/config.yaml``, which a resume no longer rewrites (Hydra's files of
a resume go to ``.hydra/resume``), :data:`TRAIN_FREE` are the keys a resume may give, and
:func:`own_training_config` gives the app the recorded config. A blue-team study (``python -m grt.blueteam``)
likewise (:data:`STUDY`): its record is Hydra's of its start too, :data:`STUDY_FREE` are the keys a resume may
give, and :func:`own_study_config` gives the app the recorded config.

Formats: 0, a folder from before ``run_config.yaml`` (a journal and Hydra's record of its start); 1, a
``run_config.yaml`` without ``grt_format``; 2, the current one. Every reader goes through
:func:`load_run_config` or :class:`SavedRun`, which :func:`migrate` the config to the current format, so no
code elsewhere needs a branch for older folders.
"""

from __future__ import annotations

import atexit
import contextlib
import copy
import errno
import fcntl
import os
import shlex
import shutil
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from hydra.errors import HydraException
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, ListConfig, OmegaConf

from grt.config import add_resolver, plain
from grt.errors import OutputError, UserError
from grt.fileio import write_text_atomic
from grt.geometry.deform import DEFAULT_RADIUS
from grt.journal import JournalError
from grt.plan import RunPlan
from grt.scores import ScoreConfigError, nominal_floor

# A run's own config, written once when it starts; what ``resume=DIR`` reads.
RUN_CONFIG = "run_config.yaml"
FORMAT_KEY = "grt_format"
FORMAT = 2
# Keys a resume may set (with what is under them): none changes the search (results are identical with any
# number of workers; loggers, the collision cache and Hydra's own files only record; the nominal floor only
# decides whether the run goes on after S0), so a resumed run stays the run its journal was written by.
SHRINK_KEYS = ("budget.shrink", "budget.shrink_ratio", "budget.shrink_min_alpha", "budget.shrink_rounds")
RESUME_FREE = ("budget.workers", "evaluator.workers", "logger", "paths.cache_dir", "hydra", "task.nominal_floor",
               "budget.confirm_trials", "budget.videos", "report", *SHRINK_KEYS)
# The parts of a resumed run's config taken from the command; all the rest is the run's saved config.
FROM_COMMAND = ("budget.workers", "evaluator.workers", "evaluator.cache_dir", "logger", "paths",
                "task.nominal_floor", "budget.confirm_trials", "budget.videos", "report", *SHRINK_KEYS)
# The evaluator's keys that shape a trial's outcome (its collision geometry); every other evaluator key only
# says where and how the trials run (evaluator=sim or ray, address, workers, timeouts), so a resume may
# change them (results are identical on the pool and on Ray) and takes them from the command.
EVALUATOR_RESULTS = ("collision", "coacd", "max_hull_vertices")
# FROM_COMMAND keys a run saved before they existed takes from the command all the same: they only choose
# what is made after the search (report.html's videos, the shrink of confirmed CrashShapes), never a result
# of the search.
AFTER_SEARCH = ("budget.videos", "report", *SHRINK_KEYS)
RUN_FOLDERS = "outputs/<task>/<object>/<policy>/<selector>-<optimizer>/<time>"
# Targets renamed since format 1: the evaluators package was ``grt.eval`` (the alias package is gone).
RENAMED_TARGETS = {"grt.eval.evaluator.SimEvaluator": "grt.evaluators.sim.SimEvaluator"}
# Keys a format-1 (or 0) config may lack, with the values such a run was made with.
ADDED_DEFAULTS = {"object_scale": 1.0, "mesh": {}, "budget.confirm_trials": 0,
                  "deformer.lam": 1.0, "deformer.method": "exact", "deformer.radius": DEFAULT_RADIUS,
                  "deformer.validity": False}
# Keys added within format 2 (issue 33): a run made before them ran without them.
ADDED_IN_FORMAT2 = {"budget.tau_rel": None, "deformer.max_volume_change": None,
                    "budget.racing": False, "budget.race_rounds": 8, "budget.race_alpha": 0.05,
                    "budget.size_penalty": 0.0}  # issue 39
# A training (``python -m grt.train``): the keys a resume may set, none of which changes what is trained:
# train.iterations only says where it stops (a resumed training continues up to it), saving a checkpoint
# draws no random number, each env's episodes are seeded by (train.seed, env index) whatever process steps
# it (train.workers), and the export, the final evaluation, loggers, the collision cache and Hydra's files
# come after the training or only record it.
TRAIN_FREE = ("train.iterations", "train.save_interval", "train.workers", "train.export",
              "train.overwrite_shipped", "eval_trials", "logger", "paths.cache_dir", "hydra")
# The parts of a resumed training's config taken from the command; all the rest is its record.
TRAIN_FROM_COMMAND = ("train.iterations", "train.save_interval", "train.workers", "train.export",
                      "train.overwrite_shipped", "eval_trials", "logger", "paths")
TRAIN_RECORD = ".hydra/config.yaml"
TRAIN_FOLDERS = "outputs/train/<task>/<train>/<time>"
# A blue-team study (``python -m grt.blueteam``): the keys a resume may set, none of which changes the study
# (its red-team run, CrashShapes, held-out shapes, episode seeds, PPO settings, guard and confirmation):
# workers only says which process steps an env (each env is seeded by its index) and how many evaluate,
# blueteam.iterations and blueteam.val_patience only where a fine-tune not yet finished stops (a finished
# one, policy.pt written, is not trained again), blueteam.rered.enabled whether a re-red-team follows the
# table, the evaluator's
# backend and workers give the same results (its collision keys stay the study's), and the collision
# cache and Hydra's files only record. With the evaluator's free keys (``_evaluator_free``).
STUDY_FREE = ("workers", "blueteam.iterations", "blueteam.val_patience", "blueteam.rered.enabled",
              "paths.cache_dir", "hydra")
# The parts of a resumed study's config taken from the command (and the evaluator but its collision keys),
# and those taken from it only when it gives them (else the record's, whatever today's defaults).
STUDY_FROM_COMMAND = ("workers", "paths")
STUDY_WHEN_GIVEN = ("blueteam.iterations", "blueteam.val_patience", "blueteam.rered.enabled")
STUDY_RECORD = TRAIN_RECORD
STUDY_FOLDERS = "outputs/blueteam/<time>"
# A robustness profile (``python -m grt.profile``): the keys a resume may set (where its trials run, the
# collision cache, Hydra's files), with the evaluator's free keys; its shapes and episodes are its record's.
PROFILE_FREE = ("budget.workers", "paths.cache_dir", "hydra")
PROFILE_FOLDERS = "RUN/profile/<time> or outputs/profile/<task>/<object>/<policy>/<time>"
# Apps whose folder may be inside a red-team run's: a profile of the run (RUN/profile/<time>, no summary.json).
INSIDE_RUN_APPS = ("profile",)
_ABSENT = object()


class ResumeError(JournalError):
    """``resume=`` of a folder that is not a run, or with settings that would change the run."""


# ----------------------------------------------------------------------------------------- validating

def is_run_folder(path: str | Path) -> bool:
    """Whether ``resume=path`` can continue a run there: the folder holds the run's own config (or, for a
    format-0 folder, a journal and Hydra's record of its start)."""
    folder = Path(path)
    return (folder / RUN_CONFIG).is_file() or (
        (folder / "journal.jsonl").is_file() and (folder / ".hydra" / "config.yaml").is_file())


def refuse_unless_run(run_dir: Path) -> None:
    """Raise :class:`ResumeError` unless ``run_dir`` is a run folder (names the problem and the fix)."""
    if not run_dir.is_dir():
        why = "no such folder"
    elif not is_run_folder(run_dir):
        why = f"not a GRT run folder (no {RUN_CONFIG})"
    else:
        return
    raise ResumeError(f"resume={run_dir}: {why}, so nothing to resume. Give the folder of an earlier run "
                      f"({RUN_FOLDERS}).")


def _holds_record(path: str | Path, keys: tuple[str, ...]) -> bool:
    """Whether ``path`` holds Hydra's record of a start (``.hydra/config.yaml``) with ``keys`` at its top,
    and no red-team run's record (an unreadable record counts: reading it names the problem)."""
    folder = Path(path)
    record = folder / TRAIN_RECORD
    if not record.is_file() or is_run_folder(folder):
        return False
    try:
        config = OmegaConf.load(record)
    except Exception:  # noqa: BLE001 - an unreadable record: SavedRun._hydra names it
        return True
    return isinstance(config, DictConfig) and all(key in config for key in keys)


def is_training_folder(path: str | Path) -> bool:
    """Whether ``resume=path`` can continue a ``grt.train`` training there: Hydra's record of its start
    (``.hydra/config.yaml`` with a ``train`` and a ``task``), and no red-team run's record."""
    return _holds_record(path, ("train", "task"))


def refuse_unless_training(run_dir: Path) -> None:
    """Raise :class:`ResumeError` unless ``run_dir`` is a training folder (names the problem and the fix)."""
    _refuse_unless(run_dir, is_training_folder(run_dir), "training", "python -m grt.train", TRAIN_FOLDERS)


def is_study_folder(path: str | Path) -> bool:
    """Whether ``resume=path`` can continue a ``grt.blueteam`` study there: Hydra's record of its start
    (``.hydra/config.yaml`` with a ``run`` and a ``blueteam``), and no red-team run's record."""
    return _holds_record(path, ("run", "blueteam"))


def is_profile_folder(path: str | Path) -> bool:
    """Whether ``resume=path`` can continue a ``grt.profile`` profile there: Hydra's record of its start
    (``.hydra/config.yaml`` with a ``profile``), and no red-team run's record."""
    return _holds_record(path, ("profile",))


def refuse_unless_profile(run_dir: Path) -> None:
    """Raise :class:`ResumeError` unless ``run_dir`` is a profile's folder (names the problem and the fix)."""
    _refuse_unless(run_dir, is_profile_folder(run_dir), "profile", "python -m grt.profile", PROFILE_FOLDERS)


def _refuse_unless(run_dir: Path, holds: bool, noun: str, app: str, folders: str) -> None:
    """Raise :class:`ResumeError` unless ``run_dir`` ``holds`` a ``noun`` of ``app`` (``folders``: where they are)."""
    if not run_dir.is_dir():
        why = "no such folder"
    elif not holds:
        why = f"not a {noun} folder of {app} (no {TRAIN_RECORD} of a {noun})"
    else:
        return
    raise ResumeError(f"resume={run_dir}: {why}, so nothing to resume. Give the folder of an earlier {noun} "
                      f"({folders}), or leave resume= out to start a new one.")


def refuse_unless_study(run_dir: Path) -> None:
    """Raise :class:`ResumeError` unless ``run_dir`` is a blue-team study's folder (names the problem and the
    fix); a red-team run's folder is named as :func:`claim` names it."""
    if is_run_folder(run_dir):
        raise ResumeError(f"resume={run_dir}: {run_dir} already holds a red-team run ({RUN_CONFIG} there), whose "
                          "files python -m grt.blueteam would overwrite or mix with its own: it is no study to "
                          f"resume. Blue-team that run with run={run_dir} (without resume=), or give resume= the "
                          f"folder of an earlier study ({STUDY_FOLDERS})")
    _refuse_unless(run_dir, is_study_folder(run_dir), "study", "python -m grt.blueteam", STUDY_FOLDERS)


def resume_or(resume: str | None, default: str) -> str:
    """``hydra.run.dir``: the resumed run's own folder, else ``default`` (a new one).

    Hydra creates this folder and writes ``.hydra/`` and ``run.log`` into it before the app runs, so a
    folder that no GRT app made is refused here, before anything is written (``python -m grt.run`` refuses
    it earlier still, with one line and exit code 2).
    """
    if not resume:
        return default
    # Shared by grt.run, grt.blueteam and grt.train: a folder one of them made (a red-team run, or Hydra's
    # record of a fine-tune / training run); grt.run checks its own kind first.
    if not Path(resume).is_dir():
        raise ResumeError(f"resume={resume}: no such folder, so nothing to resume; give the folder of an earlier "
                          "run (or leave resume= out to start a new one)")
    if not (is_run_folder(resume) or (Path(resume) / ".hydra" / "config.yaml").is_file()):
        raise ResumeError(f"resume={resume}: not a GRT run folder (no {RUN_CONFIG} or .hydra/config.yaml), "
                          "so nothing to resume")
    return str(resume)


def register() -> None:
    """Register the ``resume_or`` resolver of ``hydra.run.dir`` (idempotent)."""
    add_resolver("resume_or", resume_or)


register()


# --------------------------------------------------------------------------------- writing and reading

def save_run_config(plan: RunPlan) -> None:
    """Write the run's own record once, read-only, in ``plan.run_dir``: what ``resume=`` reads, so no later
    command rewrites it.

    ``overrides`` and ``choices`` are its command line and config-group options (Hydra's; empty when
    :func:`grt.runner.run` is called without Hydra), ``config`` its resolved config (a served policy's secret
    as given), its nominal floor written out.
    """
    path = plan.run_dir / RUN_CONFIG
    if path.exists():
        return
    config = {**copy.deepcopy(plan.config), "resume": None}
    if isinstance(config.get("task"), dict):  # every FROM_COMMAND key a run reads is here
        config["task"].setdefault("nominal_floor", plan.nominal_floor)
    record = {FORMAT_KEY: FORMAT, "overrides": list(plan.record.get("overrides", [])),
              "choices": dict(plan.record.get("choices", {})), "config": config}
    write_text_atomic(path, f"# {RUN_CONFIG}: this run as it started (written once by grt.run). Continue it "
                      f"with\n# python -m grt.run resume=<this folder>\n" + OmegaConf.to_yaml(record))
    path.chmod(0o444)


def read_record(run_dir: Path) -> tuple[int, list, dict, DictConfig]:
    """``(format, overrides, choices, config)`` as the folder stores them (not migrated).

    Format 0 is read from Hydra's files (right unless a resume of that time rewrote them).
    """
    if (run_dir / RUN_CONFIG).is_file():
        record = OmegaConf.load(run_dir / RUN_CONFIG)
        version = int(record.get(FORMAT_KEY, 1))
        overrides, choices, config = record.overrides, record.choices, record.config
    else:
        version = 0
        overrides, choices, config = _hydra_record(run_dir)
    return version, OmegaConf.to_container(overrides), OmegaConf.to_container(choices), config


def _hydra_record(run_dir: Path) -> tuple[ListConfig, DictConfig, DictConfig]:
    """``(overrides, choices, config)`` of Hydra's files in ``run_dir/.hydra``."""
    hydra_dir = run_dir / ".hydra"
    choices = OmegaConf.load(hydra_dir / "hydra.yaml").hydra.runtime.choices
    return OmegaConf.load(hydra_dir / "overrides.yaml"), choices, OmegaConf.load(hydra_dir / "config.yaml")


def migrate(cfg: DictConfig, version: int) -> DictConfig:
    """A run's config of format ``version`` in the current format (a new object; interpolations kept).

    From format 0 or 1: renamed ``_target_`` classes (:data:`RENAMED_TARGETS`, the ``grt.eval`` package)
    get their new names, and keys added since (:data:`ADDED_DEFAULTS`, ``task.nominal_floor``) get the
    values those runs were made with.
    """
    data = OmegaConf.to_container(cfg, resolve=False)
    if version < FORMAT:
        data = _rename_targets(data)
        for key, value in ADDED_DEFAULTS.items():
            _set_absent(data, key, value)
        _set_absent(data, "task.nominal_floor", _floor(data))
    for key, value in ADDED_IN_FORMAT2.items():
        _set_absent(data, key, value)
    return OmegaConf.create(data)


def load_run_config(run_dir: str | Path) -> DictConfig:
    """The red-team run's config as it ran, in the current format (see :func:`migrate`).

    Raises:
        ResumeError: ``run_dir`` is not a run folder.
    """
    run_dir = Path(run_dir)
    refuse_unless_run(run_dir)
    if (run_dir / RUN_CONFIG).is_file():
        record = OmegaConf.load(run_dir / RUN_CONFIG)
        return migrate(record.config, int(record.get(FORMAT_KEY, 1)))
    return migrate(OmegaConf.load(run_dir / ".hydra" / "config.yaml"), 0)  # format 0: Hydra's record


def _rename_targets(node):
    if isinstance(node, dict):
        return {k: RENAMED_TARGETS.get(v, v) if k == "_target_" and isinstance(v, str) else _rename_targets(v)
                for k, v in node.items()}
    if isinstance(node, list):
        return [_rename_targets(v) for v in node]
    return node


def _set_absent(data: dict, key: str, value) -> None:
    """Set dotted ``key`` in ``data`` to ``value`` unless it is there (or its parent is not a mapping)."""
    if value is _ABSENT:
        return
    *parents, last = key.split(".")
    for part in parents:
        data = data.get(part) if isinstance(data, dict) else None
        if not isinstance(data, dict):
            return
    if last not in data:
        data[last] = value


def _floor(data: dict):
    """What an absent ``task.nominal_floor`` means for the run's task (``_ABSENT``: leave it absent)."""
    task = data.get("task")
    if not isinstance(task, dict) or "nominal_floor" in task:
        return _ABSENT
    try:
        return nominal_floor(task)
    except (ScoreConfigError, ValueError):  # a bad task.ci: the run reports it itself
        return _ABSENT


# ----------------------------------------------------------------------------------------------- resuming

@dataclass
class SavedRun:
    """A run's own start, as its folder records it.

    Attributes:
        overrides: its command line's overrides (``resume=``, ``hydra.*`` and ``paths.output_dir`` left out).
        choices: its config-group options, e.g. ``{"selector": "all"}``.
        config: its config (resolved; Hydra's record for a format-0 folder), migrated to the current format.
        format: the folder's format (see the module docstring).
        started: whether the record is of the start (``False``: a training's or study's folder whose ``.hydra``
            a resume rewrote, before ``grt.train`` / ``grt.blueteam`` kept the start's record: the record of
            its latest resume).
    """

    overrides: list[str]
    choices: dict
    config: DictConfig
    format: int = FORMAT
    started: bool = True

    @classmethod
    def load(cls, run_dir: Path) -> SavedRun:
        """Read ``run_dir``; a missing folder or one that is not a run raises :class:`ResumeError`."""
        refuse_unless_run(run_dir)
        try:
            version, overrides, choices, config = read_record(run_dir)
            config = migrate(config, version)
        except Exception as exc:  # noqa: BLE001 - any unreadable record is the same user error
            raise ResumeError(f"resume={run_dir}: its record of the run cannot be read ({exc}); "
                              "start a new run") from None
        return cls(_own_overrides(overrides), _own_choices(choices), config, version)

    @classmethod
    def training(cls, run_dir: Path) -> SavedRun:
        """Read a training folder (``python -m grt.train``): Hydra's record of its start, ``DIR/.hydra``, as it
        is (a training's config has no format of its own to migrate); a missing folder or one that is not a
        training raises :class:`ResumeError`."""
        refuse_unless_training(run_dir)
        return cls._hydra(run_dir, "training")

    @classmethod
    def study(cls, run_dir: Path) -> SavedRun:
        """Read a blue-team study's folder (``python -m grt.blueteam``) as :meth:`training` reads a training's
        (``started``: ``False`` for a folder whose ``.hydra`` a resume rewrote, before ``grt.blueteam`` kept the
        start's record); a missing folder or one that is not a study raises :class:`ResumeError`."""
        refuse_unless_study(run_dir)
        return cls._hydra(run_dir, "study")

    @classmethod
    def profile(cls, run_dir: Path) -> SavedRun:
        """Read a robustness profile's folder (``python -m grt.profile``) as :meth:`training` reads a training's."""
        refuse_unless_profile(run_dir)
        return cls._hydra(run_dir, "profile")

    @classmethod
    def _hydra(cls, run_dir: Path, noun: str) -> SavedRun:
        """Hydra's record in ``run_dir/.hydra`` of the start of a ``noun`` (``training``, ``study``)."""
        try:
            overrides, choices, config = _hydra_record(run_dir)
            own = _own_overrides(OmegaConf.to_container(overrides))
            choices = _own_choices(OmegaConf.to_container(choices))
            started = config.get("resume") is None  # a resume's record names the folder it resumed
        except Exception as exc:  # noqa: BLE001 - any unreadable record is the same user error
            raise ResumeError(f"resume={run_dir}: its record of the {noun} ({TRAIN_RECORD} and the files "
                              f"beside it) cannot be read ({exc}); start a new {noun}") from None
        return cls(own, choices, config, 0, started)

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


def _own_overrides(overrides: list[str]) -> list[str]:
    """A start's overrides but those no part of the run: ``resume=``, ``hydra.*``, the output folder."""
    return [o for o in overrides if not _under(_key(o), ("resume", "hydra", "paths.output_dir"))]


def _own_choices(choices: dict) -> dict:
    return {k: v for k, v in choices.items() if not _under(k, ("hydra",))}


@dataclass(frozen=True)
class Resumable:
    """One kind of folder ``resume=DIR`` continues, for :func:`resume_overrides`.

    Attributes:
        load: reads DIR's record (raises :class:`ResumeError` for a folder of another kind).
        free: whether a resume may give a key (it cannot change what the folder's work is).
        noun: what the folder holds, in a refusal ("run", "training", "study").
        record: the file of DIR that keeps its config, named in a refusal.
        allowed: the keys a resume may give, as a refusal lists them.
    """

    load: Callable[[Path], SavedRun]
    free: Callable[[str], bool]
    noun: str
    record: str
    allowed: str


# A red-team run (python -m grt.run) and a training (python -m grt.train).
RUN = Resumable(SavedRun.load, lambda key: _under(key, RESUME_FREE) or _evaluator_free(key), "run", RUN_CONFIG,
                f"{', '.join(RESUME_FREE)}.*, evaluator=sim|ray and the evaluator's keys but "
                f"{', '.join(EVALUATOR_RESULTS)}")
TRAINING = Resumable(SavedRun.training, lambda key: _under(key, TRAIN_FREE), "training", TRAIN_RECORD,
                     f"{', '.join(TRAIN_FREE)}.*")
# A blue-team study (python -m grt.blueteam).
PROFILE = Resumable(SavedRun.profile, lambda key: _under(key, PROFILE_FREE) or _evaluator_free(key), "profile",
                    TRAIN_RECORD, f"{', '.join(PROFILE_FREE)}.*, evaluator=sim|ray and the evaluator's keys but "
                    f"{', '.join(EVALUATOR_RESULTS)}")
STUDY = Resumable(SavedRun.study, lambda key: _under(key, STUDY_FREE) or _evaluator_free(key), "study", STUDY_RECORD,
                  f"{', '.join(STUDY_FREE)}.*, evaluator=sim|ray and the evaluator's keys but "
                  f"{', '.join(EVALUATOR_RESULTS)}")


def resume_overrides(overrides: list[str], kind: Resumable = RUN) -> list[str]:
    """The overrides Hydra gets for a command with ``resume=DIR``: the run's own ones.

    Called before Hydra starts, so a refused resume writes nothing. The other overrides given must be free
    keys of ``kind`` (a red-team run's: :data:`RESUME_FREE`; a training's: :data:`TRAIN_FREE`; a study's:
    :data:`STUDY_FREE` and the evaluator's keys but :data:`EVALUATOR_RESULTS`) or give the
    run's own values; the free ones are passed on, and Hydra writes its files of a resume under
    ``DIR/.hydra/resume`` (``DIR/.hydra`` stays the record of the start).

    Returns:
        ``overrides`` unchanged without ``resume=``.

    Raises:
        ResumeError: DIR is missing or not a run (of ``kind``), empty (``resume=`` of an unset shell variable;
            ``resume=null`` is no resume), or an override would change the run (names the keys).
    """
    try:
        given = OverridesParser.create().parse_overrides(overrides)
    except HydraException:
        return overrides  # Hydra reports a malformed override itself
    resume = [o for o in given if o.key_or_group == "resume"]
    if resume and isinstance(resume[-1].value(), str) and not resume[-1].value().strip():
        raise ResumeError(f"{resume[-1].input_line.strip()!r}: resume= is empty (an unset shell variable?), and a "
                          f"new {kind.noun} is not what resume= asks for: give the folder to continue "
                          f"(resume=DIR), or leave resume= out to start a new {kind.noun}")
    if not resume or not resume[-1].value():
        return overrides
    run_dir = resume[-1].value()
    if not isinstance(run_dir, str):
        raise ResumeError(f"{resume[-1].input_line}: resume= takes one run folder")
    saved = kind.load(Path(run_dir))
    if kind is RUN:
        refuse_edited_record(Path(run_dir))
    free = [o for o in given if kind.free(o.key_or_group)]
    changed = [o for o in given if o.key_or_group != "resume" and o not in free and not saved.keeps(o)]
    if changed:
        what = ", ".join(f"{o.key_or_group} (the {kind.noun}'s: {_shown_value(saved.value(o.key_or_group))}, "
                         f"given: {o.input_line.partition('=')[2] or 'deleted'})" for o in changed)
        raise ResumeError(
            f"resume={run_dir}: {what} would change the {kind.noun}, which keeps its own config ({kind.record} "
            f"there). Continue it with resume={run_dir} alone (allowed with it: {kind.allowed}), "
            f"or start a new {kind.noun} with these settings: the same command without resume=")
    own = [line for line in saved.overrides if not any(_under(_key(line), (o.key_or_group,)) for o in free)]
    return [*own, "hydra.output_subdir=.hydra/resume", *(o.input_line for o in free), resume[-1].input_line]


# Keys of a run's record not compared with Hydra's record of its start (:func:`record_edits`): those a resume
# may give (they do not change the run), where the run ran, and values kept as given (the policy's token).
_NOT_COMPARED = (*RESUME_FREE, *FROM_COMMAND, "paths", "resume", "policy.token", "evaluator")


def record_edits(run_dir: Path) -> list[str]:
    """Where a run's own record (``run_config.yaml``) and Hydra's record of its start (``.hydra/config.yaml``,
    which a resume never rewrites) disagree on a key that shapes the run: ``["object (run_config.yaml: bottle,
    .hydra/config.yaml: mug)", ...]``; empty when they agree or there is no second record to compare with
    (a format-0 folder, a run started from Python). Keys a resume may change, and values that do not resolve
    outside the run (``${hydra:...}``), are not compared; the evaluator's collision keys are."""
    record, start = run_dir / RUN_CONFIG, run_dir / TRAIN_RECORD
    if not record.is_file() or not start.is_file():
        return []
    try:
        saved, started = OmegaConf.load(record).config, OmegaConf.load(start)
    except Exception:  # noqa: BLE001 - an unreadable record: SavedRun.load names it
        return []
    found: list[str] = []
    _compare(saved, started, started, "", found)
    evaluator = saved.get("evaluator") if isinstance(saved.get("evaluator"), DictConfig) else {}
    for key in EVALUATOR_RESULTS:
        if key in evaluator:
            _compare_leaf(evaluator[key], started, f"evaluator.{key}", found)
    return found


def _compare(saved: DictConfig, node: DictConfig, started: DictConfig, prefix: str, found: list[str]) -> None:
    for key in saved:
        path = f"{prefix}{key}"
        if _under(path, _NOT_COMPARED) or key not in node:
            continue
        if isinstance(saved[key], DictConfig) and isinstance(node._get_node(key), DictConfig):
            _compare(saved[key], node[key], started, f"{path}.", found)
        else:
            _compare_leaf(saved[key], started, path, found)


def _compare_leaf(value, started: DictConfig, path: str, found: list[str]) -> None:
    try:
        had = OmegaConf.select(started, path, throw_on_resolution_failure=True)
    except Exception:  # noqa: BLE001 - e.g. ${hydra:...}: nothing to compare with outside the run
        return
    mine = OmegaConf.to_container(value, resolve=True) if isinstance(value, (DictConfig, ListConfig)) else value
    had = OmegaConf.to_container(had, resolve=True) if isinstance(had, (DictConfig, ListConfig)) else had
    if mine != had:
        found.append(f"{path} ({RUN_CONFIG}: {mine}, {TRAIN_RECORD}: {had})")


def refuse_edited_record(run_dir: Path) -> None:
    """Raise :class:`ResumeError` when the run's record was edited since it started (:func:`record_edits`),
    before anything is written: a resume would otherwise run another config over the run's journal."""
    edits = record_edits(run_dir)
    if edits:
        shown = "; ".join(edits[:3]) + (f"; and {len(edits) - 3} more" if len(edits) > 3 else "")
        raise ResumeError(f"resume={run_dir}: the run's record was edited after it started, its two records "
                          f"differ: {shown}. A run keeps the config it started with: restore {RUN_CONFIG} (the "
                          f"start's values are in {TRAIN_RECORD}), or start a new run with the new settings "
                          "(the same command without resume=)")


def own_config(cfg: DictConfig) -> DictConfig:
    """A resumed run's config: its saved one, with the :data:`FROM_COMMAND` parts of this command.

    A format-0 folder has no resolved record of its config: ``cfg``, composed from its own overrides
    (:func:`resume_overrides`), is its config.
    """
    saved = SavedRun.load(Path(cfg.resume))
    if saved.format == 0:
        return cfg
    own = OmegaConf.create(OmegaConf.to_container(saved.config))
    for key in FROM_COMMAND:
        value = OmegaConf.select(cfg, key, default=_ABSENT)
        if value is not _ABSENT and (OmegaConf.select(own, key, default=_ABSENT) is not _ABSENT
                                     or key in AFTER_SEARCH):
            OmegaConf.update(own, key, plain(value) if isinstance(value, DictConfig) else value, merge=False)
    if isinstance(cfg.get("evaluator"), DictConfig):  # the backend of this command, the run's collision geometry
        evaluator, saved_ev = plain(cfg.evaluator), own.get("evaluator") or {}
        evaluator.update({k: plain(saved_ev[k]) if isinstance(saved_ev[k], DictConfig) else saved_ev[k]
                          for k in EVALUATOR_RESULTS if k in saved_ev})
        if _on_gpu(saved_ev) != _on_gpu(evaluator):  # the GPU's physics is not the CPU's: one journal, one
            was, now = ("evaluator=gpu", "CPU workers") if _on_gpu(saved_ev) else ("CPU workers", "evaluator=gpu")
            raise ResumeError(f"resume={cfg.resume}: the run's trials were simulated with {was}, this command would "
                              f"go on with {now}, whose physics differs: resume it with "
                              f"{'evaluator=gpu' if _on_gpu(saved_ev) else 'evaluator=sim or evaluator=ray'}")
        own.evaluator = evaluator
    own.resume = cfg.resume
    return own


def _on_gpu(evaluator) -> bool:
    """Whether an evaluator config simulates on a GPU (``evaluator=gpu`` on ``physx_cuda``; on ``physx_cpu``
    its trials are the CPU workers' bit for bit)."""
    return str(evaluator.get("_target_", "")).endswith(".GpuEvaluator") and evaluator.get("backend") != "physx_cpu"


def own_training_config(cfg: DictConfig) -> DictConfig:
    """A resumed training's config: its record (``DIR/.hydra/config.yaml``, as composed at its start, its
    interpolations kept), with the :data:`TRAIN_FROM_COMMAND` parts of this command (``cfg``: composed by
    Hydra from the training's own overrides and the free ones, :func:`resume_overrides`)."""
    saved = SavedRun.training(Path(cfg.resume))
    own = OmegaConf.create(OmegaConf.to_container(saved.config, resolve=False))
    for key in TRAIN_FROM_COMMAND:
        value = OmegaConf.select(cfg, key, default=_ABSENT)
        if value is not _ABSENT:
            OmegaConf.update(own, key, plain(value) if isinstance(value, DictConfig) else value, merge=False)
    own.resume = cfg.resume
    return own


def own_study_config(cfg: DictConfig, overrides: list[str] | None = None) -> DictConfig:
    """A resumed blue-team study's config: its record (``DIR/.hydra/config.yaml``, as composed at its start,
    its interpolations kept), with the :data:`STUDY_FROM_COMMAND` parts of this command (``cfg``: composed by
    Hydra from the study's own overrides and the free ones, :func:`resume_overrides`), the
    :data:`STUDY_WHEN_GIVEN` ones it sets (``overrides``: Hydra's; by default this job's), and this command's
    evaluator but the study's collision keys (:data:`EVALUATOR_RESULTS`)."""
    saved = SavedRun.study(Path(cfg.resume))
    own = OmegaConf.create(OmegaConf.to_container(saved.config, resolve=False))
    if overrides is None:
        overrides = list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []
    given = {_key(o) for o in overrides}
    for key in (*STUDY_FROM_COMMAND, *(k for k in STUDY_WHEN_GIVEN if k in given)):
        value = OmegaConf.select(cfg, key, default=_ABSENT)
        if value is not _ABSENT:
            OmegaConf.update(own, key, plain(value) if isinstance(value, DictConfig) else value, merge=False)
    if isinstance(cfg.get("evaluator"), DictConfig):
        evaluator, saved_ev = plain(cfg.evaluator), own.get("evaluator") or {}
        evaluator.update({k: OmegaConf.to_container(saved_ev[k]) if isinstance(saved_ev[k], DictConfig)
                          else saved_ev[k] for k in EVALUATOR_RESULTS if k in saved_ev})
        own.evaluator = evaluator
    own.resume = cfg.resume
    return own


def interrupted(run_dir: Path, how: str = "interrupted (Ctrl-C)") -> str:
    """The line printed on Ctrl-C (``how``: or SIGTERM): how to continue the run (or that nothing of it was
    saved yet)."""
    if not is_run_folder(run_dir):
        return f"{how} before the run saved its config; start it again with the same command"
    return f"{how}; continue this run with: {resume_command(run_dir)}"


def resume_command(run_dir: Path) -> str:
    """``python -m grt.run resume=DIR`` (DIR relative to the working folder when under it), quoted so that it
    works when pasted into a shell whatever DIR's name holds (:func:`override_arg`)."""
    run_dir = Path(run_dir)
    shown = Path(os.path.relpath(run_dir)) if run_dir.resolve().is_relative_to(Path.cwd()) else run_dir
    return f"python -m grt.run {override_arg('resume', str(shown))}"


def override_arg(key: str, value: str) -> str:
    """``key=value`` as one shell word that Hydra's override parser reads back as ``value``: as it is when both
    take it so, else the value in Hydra's quotes (a space, a non-ASCII letter or one of ``()[]{},'"`` needs
    them) inside the shell's (``'resume="/data/my run (2)"'``)."""
    escaped = value.replace("\\", "\\\\").replace("'", "\\'")
    for arg in (f"{key}={value}", f'{key}="{value}"', f"{key}='{value}'", f"{key}='{escaped}'"):
        try:
            override = OverridesParser.create().parse_override(arg)
        except HydraException:
            continue
        if override.key_or_group == key and override.value() == value:
            return shlex.quote(arg)
    return shlex.quote(f"{key}={value}")  # no form Hydra reads back (never seen): the plain one, in a message


def storage_error(exc: BaseException, run_dir: Path) -> str | None:
    """One line for a run that could not write its files (disk full, quota, read-only or forbidden folder)
    anywhere in ``exc``'s chain, naming the disk and how to go on; ``None`` for other errors."""
    for _ in range(10):
        if exc is None or (isinstance(exc, OSError) and exc.errno in _STORAGE):
            break
        exc = exc.__cause__ or exc.__context__
    if not isinstance(exc, OSError) or exc.errno not in _STORAGE:
        return None
    where = f"writing {exc.filename}" if exc.filename else f"writing in {run_dir}"
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        what = f"the disk of {_mount_point(run_dir)} is full ({exc.strerror}, {where})"
        fix = "free space there"
    else:
        what = f"cannot write the run's files ({exc.strerror}, {where})"
        fix = "make the folder writable"
    if is_run_folder(run_dir):
        return f"{what}; the journal keeps every finished candidate: {fix}, then continue with: " \
               f"{resume_command(run_dir)}"
    return f"{what}; nothing of the run was saved: {fix} (or give another folder, hydra.run.dir=PATH) and " \
           "start it again with the same command"


_STORAGE = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM)


def _mount_point(path: Path) -> Path:
    path = Path(os.path.abspath(path))
    while not path.exists() or not os.path.ismount(path):
        if path.parent == path:
            break
        path = path.parent
    return path


# ------------------------------------------------------------------------------------- one run, one folder

LOCK = ".grt.lock"  # in the run folder while a process runs there: its PID, under an exclusive flock


class FolderBusyError(UserError):
    """Another process holds the run folder's lock."""


class FolderNotEmptyError(UserError):
    """A new run (of any GRT app) given a folder that already holds files: the user's, or another command's."""


# What Hydra writes when an app starts (besides ``<app>.log``): a folder holding only these and the log is a
# start that was killed before it saved anything, which a new start may take over.
HYDRA_RECORD = {"config.yaml", "hydra.yaml", "overrides.yaml"}


_held: dict[Path, int] = {}  # run folder (resolved) -> this process's locked file descriptor of its LOCK
_claimed: dict[Path, tuple[Path | None, set[str], set[str]]] = {}  # run folder -> (first folder made for it,
# what the folder held before this command, the names of Hydra's files)


def acquire(run_dir: str | Path) -> bool:
    """Take ``run_dir``'s exclusive lock (an ``flock`` on ``run_dir/.grt.lock``, holding this PID) for this
    process's run; ``False`` if this process holds it already. The folder must exist. The kernel releases
    the lock when the process ends, however it ends (a SIGKILL leaves the file, never a stale lock).

    Raises:
        FolderBusyError: another process holds it (names the folder and that process's PID).
        OSError: the lock file cannot be written.
    """
    key = Path(run_dir).resolve()
    if key in _held:
        return False
    path = key / LOCK
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise FolderBusyError(
                f"{run_dir} is in use by another GRT process (PID {holder}, which holds {path}): two processes in "
                "one folder would mix their files (a run's journal, a fine-tune's checkpoints). Wait for it to end "
                "(or stop it), or give this command another folder (hydra.run.dir=PATH)") from None
        try:  # the previous holder removes the file as it lets go: locked, it must still be the file
            current = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            current = False
        if current:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    except OSError:
        os.close(fd)
        raise
    _held[key] = fd
    return True


def release(run_dir: str | Path) -> None:
    """Let go of ``run_dir``'s lock if this process holds it (the lock file is removed)."""
    key = Path(run_dir).resolve()
    fd = _held.pop(key, None)
    if fd is None:
        return
    with contextlib.suppress(OSError):
        os.unlink(key / LOCK)  # before closing: a process waiting on it sees another file and retries
    os.close(fd)


@contextlib.contextmanager
def locked(run_dir: str | Path) -> Iterator[None]:
    """Hold ``run_dir``'s lock for the block (nothing to do if this process holds it already)."""
    took = acquire(run_dir)
    try:
        yield
    finally:
        if took:
            release(run_dir)


@atexit.register
def _release_all() -> None:
    for key in list(_held):
        release(key)


def claim(run_dir: Path, resume: str | None, log_file: str = "run.log", app: str = "run") -> None:
    """Make and lock the folder of a GRT app's run (``python -m grt.<app>``) before Hydra writes anything
    into it.

    Refuses a new run in a folder that holds a red-team run (its record would be rewritten and two runs'
    journals mixed; or, for another app, the run's files overwritten by its own), a new run in any other
    folder that is not empty (:func:`check_new_folder`: the user's own files, or another command's), and a
    folder another process runs in; notes what this command makes, so that a run refused before it saved
    anything leaves nothing behind (:func:`discard_new`). ``log_file``: the name of Hydra's log file
    (``<app>.log``).

    Raises:
        ResumeError: a new run (no ``resume=``) in a red-team run's folder, or another app's command (resumed
            or not) there: only ``grt.run`` continues a red-team run.
        FolderNotEmptyError: a new run in a folder that holds other files.
        FolderBusyError: another process holds the folder's lock.
        OutputError: the folder cannot be made or written.
    """
    # absolute: discard_new gets Hydra's absolute output_dir, the callback may get a relative run.dir
    first_new = next((p for p in reversed([run_dir.resolve(), *run_dir.resolve().parents]) if not p.exists()), None)
    hydra_files = {".hydra", log_file}
    before = set(os.listdir(run_dir)) if run_dir.is_dir() else set()
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        acquire(run_dir)  # first: a folder a run is running in is "in use", whatever this command is
    except OSError as exc:
        _remove_new(run_dir, first_new)
        raise OutputError(f"cannot write the run folder {run_dir}: {exc.strerror}; give a folder you can write to "
                          "(hydra.run.dir=PATH)") from None
    if is_run_folder(run_dir) and (app != "run" or not resume):
        release(run_dir)
        if app != "run":  # only grt.run continues a red-team run; any other app would write over its files
            given = f"resume={resume}: {run_dir}" if resume else f"hydra.run.dir={run_dir}"
            raise ResumeError(f"{given} already holds a red-team run ({RUN_CONFIG} there), whose "
                              f"files python -m grt.{app} would overwrite or mix with its own: give it a folder of "
                              "its own (hydra.run.dir=PATH, or leave it out for a new one)")
        raise ResumeError(f"hydra.run.dir={run_dir} already holds a run ({RUN_CONFIG} there), which this command "
                          f"would overwrite: continue it with {resume_command(run_dir)}, or give a new folder")
    if not resume or Path(resume).resolve() != run_dir.resolve():
        try:
            check_new_folder(run_dir, before, app, log_file)
        except FolderNotEmptyError:
            release(run_dir)
            _remove_new(run_dir, first_new)  # a folder made inside a run's: not left there
            raise
    _claimed[run_dir.resolve()] = (first_new, before, hydra_files)


def check_new_folder(run_dir: Path, before: set[str], app: str, log_file: str) -> None:
    """Refuse a new run of ``python -m grt.<app>`` in ``run_dir`` unless the folder is new or empty (``before``:
    the names it held), or holds only a start of the same app killed before it saved anything (Hydra's
    record and ``log_file``), or is a folder the app continues in place (a ``grt.blueteam`` study, a
    ``grt.train`` training).

    A folder inside a red-team run's folder is refused too, whatever it holds, but a robustness profile's
    (:data:`INSIDE_RUN_APPS`): ``python -m grt.profile run=RUN`` writes ``RUN/profile/<time>`` (no summary, so
    ``grt.report RUN`` reads it as the run's profile, never as another run).

    Raises:
        FolderNotEmptyError: names the folder, what it holds (or the run it is inside) and what to do.
    """
    outer = next((p for p in Path(run_dir).resolve().parents if is_run_folder(p)), None)
    if outer is not None and app not in INSIDE_RUN_APPS:  # its files would join the run's (grt.report would average)
        raise FolderNotEmptyError(f"{run_dir} is inside the red-team run {outer}: a new python -m grt.{app} there "
                                  "would mix its files with that run's (python -m grt.report would read both as one "
                                  "folder's); give a folder outside it (hydra.run.dir=PATH)")
    held = sorted(before - {LOCK})
    hydra = run_dir / ".hydra"
    killed_start = set(held) <= {".hydra", log_file} and (
        not hydra.is_dir() or {p.name for p in hydra.iterdir()} <= HYDRA_RECORD)
    in_place = (app == "blueteam" and is_study_folder(run_dir)) or (app == "train" and is_training_folder(run_dir))
    if not held or killed_start or in_place:
        return
    shown = ", ".join(held[:4]) + (f" and {len(held) - 4} more" if len(held) > 4 else "")
    flag = "hydra.run.dir=PATH" + (" or out_dir=PATH" if app == "select" else "")
    raise FolderNotEmptyError(f"{run_dir} is not empty (it holds {shown}): a new python -m grt.{app} starts only in a "
                              f"new or empty folder, so that nothing there is overwritten or mixed with its files; "
                              f"give another folder ({flag}), or leave it out for a new one")


def check_in_place(run_dir: Path, config: DictConfig, app: str) -> None:
    """Refuse a ``grt.train`` (``grt.blueteam``) command without ``resume=`` whose ``hydra.run.dir`` holds a
    training (a study) started with other settings: continued in place, it would go on from that folder's
    ``last.pt`` with this command's settings and write Hydra's record of them over the record of its start.
    The same command again (a requeued job), or one that changes only what a resume may change, goes on.

    Raises:
        ResumeError: names the settings that differ and the two ways on (``resume=DIR``, another folder).
    """
    if OmegaConf.select(config, "resume"):
        return
    if app == "train" and is_training_folder(run_dir):
        noun, free, command = "training", lambda key: _under(key, TRAIN_FREE), "python -m grt.train"
    elif app == "blueteam" and is_study_folder(run_dir):
        noun, free, command = "study", lambda key: _under(key, STUDY_FREE) or _evaluator_free(key), \
            "python -m grt.blueteam"
    else:
        return
    try:
        saved = _leaves(OmegaConf.to_container(OmegaConf.load(run_dir / ".hydra" / "config.yaml"), resolve=False))
    except Exception:  # noqa: BLE001 - an unreadable record: the app's own resume checks name it
        return
    now = _leaves(OmegaConf.to_container(config, resolve=False))
    changed = sorted(k for k in set(saved) | set(now) if not free(k) and k != "resume"
                     and saved.get(k, _ABSENT) != now.get(k, _ABSENT))
    changed = [k for k in changed if not any(k.startswith(f"{c}.") for c in changed)]  # train.bc, not its keys
    if not changed:
        return
    release(run_dir)

    def value(leaves: dict, key: str) -> str:
        if key in leaves:
            return _shown_value(leaves[key])
        return "a mapping" if any(k.startswith(f"{key}.") for k in leaves) else "unset"

    shown = ", ".join(f"{k} (the {noun}'s: {value(saved, k)}, this command's: {value(now, k)})"
                      for k in changed[:4])
    more = f" and {len(changed) - 4} more" if len(changed) > 4 else ""
    raise ResumeError(f"hydra.run.dir={run_dir} holds a {noun} started with other settings: {shown}{more}; "
                      f"continued in place it would go on from its last.pt with this command's. Continue it "
                      f"with {command} resume={run_dir} (its own settings), or give a new folder for these")


def _leaves(node, prefix: str = "") -> dict:
    """A config's leaves by dotted key (lists kept whole), its ``hydra`` node left out."""
    out = {}
    for key, value in (node.items() if isinstance(node, dict) else ()):
        path = f"{prefix}{key}"
        if path == "hydra":
            continue
        if isinstance(value, dict) and value:
            out.update(_leaves(value, f"{path}."))
        else:
            out[path] = value
    return out


def discard_new(run_dir: Path) -> str:
    """Remove what this command made for a run that saved nothing (the folder holds only Hydra's files):
    the folder it created, or its Hydra files in a folder that was there. Returns the words saying so
    ("" if nothing was removed)."""
    key = Path(run_dir).resolve()
    if key not in _claimed or is_run_folder(run_dir):
        return ""
    first_new, before, hydra_files = _claimed[key]
    made = {p.name for p in run_dir.iterdir()} - before - {LOCK} if run_dir.is_dir() else set()
    if not made <= hydra_files:  # the command saved something of its own: keep it all
        return ""
    del _claimed[key]
    release(run_dir)
    if first_new is not None:
        _remove_new(run_dir, first_new)
        return f"nothing was saved and the new folder {run_dir} was removed"
    for name in made:
        path = run_dir / name
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return f"nothing was saved in {run_dir}"


def _remove_new(run_dir: Path, first_new: Path | None) -> None:
    """Remove ``run_dir`` and the empty folders above it up to ``first_new`` (those this command made)."""
    if first_new is None:
        return
    run_dir, first_new = Path(run_dir).resolve(), Path(first_new).resolve()
    made = [run_dir, *run_dir.parents]
    if first_new not in made:  # not a folder this command made above the run's: remove nothing
        return
    shutil.rmtree(run_dir, ignore_errors=True)
    for folder in made[1:made.index(first_new) + 1]:
        with contextlib.suppress(OSError):
            folder.rmdir()  # only an empty one: a folder another run made meanwhile stays


class RunFolderCallback(Callback):
    """Hydra callback of every app that writes a run folder: ``grt.run`` (``conf/hydra/default.yaml``),
    ``grt.train``, ``grt.blueteam``, ``grt.evaluate`` and ``grt.select`` (their root configs): :func:`claim`
    the run folder before Hydra makes it and writes its record there, so two processes never share one
    (a second ``grt.blueteam resume=DIR`` of a study still running is refused, not mixed into it). A
    ``grt.run`` sweep's jobs (new folders each) are locked by :func:`grt.runner.run`. Hydra turns a
    callback's exception into a warning and goes on, so a refusal is the apps' one ``error:`` line on
    stderr here, and exit code 2."""

    def on_run_start(self, config: DictConfig, **kwargs) -> None:
        HydraConfig.instance().set_config(config)  # hydra.run.dir reads ${hydra:runtime.choices...}
        try:
            run_dir = Path(str(config.hydra.run.dir))
        except Exception:  # noqa: BLE001 - e.g. an unknown object in the folder's name: Hydra reports it
            return
        try:
            claim(run_dir, OmegaConf.select(config, "resume"), f"{config.hydra.job.name}.log",
                  str(config.hydra.job.name))
            check_in_place(run_dir, config, str(config.hydra.job.name))
        except UserError as exc:
            print(f"error: {exc}", file=sys.stderr, flush=True)
            raise SystemExit(2) from None

    def on_run_end(self, config: DictConfig, **kwargs) -> None:
        release(Path(str(config.hydra.run.dir)))


def _key(override: str) -> str:
    return OverridesParser.create().parse_override(override).key_or_group


def _under(key: str, prefixes: tuple[str, ...]) -> bool:
    """Whether ``key`` is one of ``prefixes`` or lies under one (``logger.mode``, ``hydra/launcher``)."""
    return any(key == p or key.startswith((f"{p}.", f"{p}/")) for p in prefixes)


def _evaluator_free(key: str) -> bool:
    """Whether a resume may give ``key``: the evaluator group (``evaluator=ray``) or one of its keys that do
    not shape results (:data:`EVALUATOR_RESULTS`)."""
    if key == "evaluator":
        return True
    return key.startswith("evaluator.") and not _under(key.removeprefix("evaluator."), EVALUATOR_RESULTS)


def _shown_value(value) -> str:
    return "unset" if value is _ABSENT else str(value)
