"""A run folder's record: what a run, a training or a study keeps of its start, read and written here alone.

A red-team run writes its own record once, when it starts, to ``run_config.yaml`` (read-only)::

    grt_format: 2          # the folder's format (absent: format 1)
    overrides: [...]       # its command line (Hydra's; resume=, hydra.* and paths.output_dir left out)
    choices: {...}         # its config-group options
    config: {...}          # its resolved config (a served policy's secret as given, never its value)

Formats: 0, a folder from before ``run_config.yaml`` (a journal and Hydra's record of its start); 1, a
``run_config.yaml`` without ``grt_format``; 2, the current one. Every reader goes through
:func:`load_run_config` or :func:`read_record`, and :func:`migrate` brings the config to the current
format, so no code elsewhere needs a branch for older folders. A training's (``python -m grt.train``) and a
blue-team study's (``python -m grt.blueteam``) record is Hydra's of its start, ``.hydra/config.yaml``.

The record is the lowest part of :mod:`grt.runfolder`: :mod:`grt.runfolder.resume` (what a resume may
change) and :mod:`grt.runfolder.lock` (one process per folder) read it. The YAML and the override grammar
are Hydra's, read through :mod:`grt.config.records` as plain data.
"""

from __future__ import annotations

import copy
import errno
import os
import shlex
from pathlib import Path

from grt.config.records import override_key, read_yaml, reads_back, yaml_text
from grt.fileio import write_text_atomic
from grt.geometry.deform import DEFAULT_RADIUS
from grt.journal import JournalError
from grt.plan import RunPlan
from grt.scores import ScoreConfigError, nominal_floor

# A run's own config, written once when it starts; what ``resume=DIR`` reads.
RUN_CONFIG = "run_config.yaml"
FORMAT_KEY = "grt_format"
FORMAT = 2
RUN_FOLDERS = "outputs/<task>/<object>/<policy>/<selector>-<optimizer>/<time>"
# Targets renamed since format 1: the evaluators package was ``grt.eval`` (the alias package is gone).
RENAMED_TARGETS = {"grt.eval.evaluator.SimEvaluator": "grt.evaluators.sim.SimEvaluator"}
# Keys a format-1 (or 0) config may lack, with the values such a run was made with.
ADDED_DEFAULTS = {"object_scale": 1.0, "mesh": {}, "budget.confirm_trials": 0,
                  "deformer.lam": 1.0, "deformer.method": "exact", "deformer.radius": DEFAULT_RADIUS,
                  "deformer.validity": False}
# Keys added within format 2: a run made before them ran without them.
ADDED_IN_FORMAT2 = {"budget.tau_rel": None, "deformer.max_volume_change": None,
                    "budget.racing": False, "budget.race_rounds": 8, "budget.race_alpha": 0.05,
                    "budget.size_penalty": 0.0}
# Hydra's record of a start: a training's and a study's own, a format-0 run's.
TRAIN_RECORD = ".hydra/config.yaml"
TRAIN_FOLDERS = "outputs/train/<task>/<train>/<time>"
STUDY_RECORD = TRAIN_RECORD
STUDY_FOLDERS = "outputs/blueteam/<time>"
PROFILE_FOLDERS = "RUN/profile/<time> or outputs/profile/<task>/<object>/<policy>/<time>"
ABSENT = object()  # a key a config does not have


class ResumeError(JournalError):
    """``resume=`` of a folder that is not a run, or with settings that would change the run."""


# ----------------------------------------------------------------------------------------- which folder

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
        config = read_yaml(record)
    except Exception:  # noqa: BLE001 - an unreadable record: SavedRun._hydra names it
        return True
    return isinstance(config, dict) and all(key in config for key in keys)


def is_training_folder(path: str | Path) -> bool:
    """Whether ``resume=path`` can continue a ``grt.train`` training there: Hydra's record of its start
    (``.hydra/config.yaml`` with a ``train`` and a ``task``), and no red-team run's record."""
    return _holds_record(path, ("train", "task"))


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


def refuse_unless_training(run_dir: Path) -> None:
    """Raise :class:`ResumeError` unless ``run_dir`` is a training folder (names the problem and the fix)."""
    _refuse_unless(run_dir, is_training_folder(run_dir), "training", "python -m grt.train", TRAIN_FOLDERS)


def refuse_unless_study(run_dir: Path) -> None:
    """Raise :class:`ResumeError` unless ``run_dir`` is a blue-team study's folder (names the problem and the
    fix); a red-team run's folder is named as :func:`grt.runfolder.lock.claim` names it."""
    if is_run_folder(run_dir):
        raise ResumeError(f"resume={run_dir}: {run_dir} already holds a red-team run ({RUN_CONFIG} there), whose "
                          "files python -m grt.blueteam would overwrite or mix with its own: it is no study to "
                          f"resume. Blue-team that run with run={run_dir} (without resume=), or give resume= the "
                          f"folder of an earlier study ({STUDY_FOLDERS})")
    _refuse_unless(run_dir, is_study_folder(run_dir), "study", "python -m grt.blueteam", STUDY_FOLDERS)


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


def resume_or(resume: str | None, default: str) -> str:
    """``hydra.run.dir`` (the resolver ``resume_or``): the resumed run's own folder, else ``default`` (a new one).

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
    if isinstance(config.get("task"), dict):  # every key a resume takes from the command is here
        config["task"].setdefault("nominal_floor", plan.nominal_floor)
    record = {FORMAT_KEY: FORMAT, "overrides": list(plan.record.get("overrides", [])),
              "choices": dict(plan.record.get("choices", {})), "config": config}
    write_text_atomic(path, f"# {RUN_CONFIG}: this run as it started (written once by grt.run). Continue it "
                      f"with\n# python -m grt.run resume=<this folder>\n" + yaml_text(record))
    path.chmod(0o444)


def read_record(run_dir: Path) -> tuple[int, list, dict, dict]:
    """``(format, overrides, choices, config)`` as the folder stores them (not migrated; plain data, the
    config's interpolations as written).

    Format 0 is read from Hydra's files (right unless a resume of that time rewrote them).
    """
    if (run_dir / RUN_CONFIG).is_file():
        record = read_yaml(run_dir / RUN_CONFIG)
        return int(record.get(FORMAT_KEY, 1)), record["overrides"], record["choices"], record["config"]
    return (0, *hydra_record(run_dir))


def hydra_record(run_dir: Path) -> tuple[list, dict, dict]:
    """``(overrides, choices, config)`` of Hydra's files in ``run_dir/.hydra``."""
    hydra_dir = run_dir / ".hydra"
    choices = read_yaml(hydra_dir / "hydra.yaml")["hydra"]["runtime"]["choices"]
    return read_yaml(hydra_dir / "overrides.yaml"), choices, read_yaml(hydra_dir / "config.yaml")


def migrate(config: dict, version: int) -> dict:
    """A run's config of format ``version`` in the current format (a new mapping; interpolations kept).

    From format 0 or 1: renamed ``_target_`` classes (:data:`RENAMED_TARGETS`, the ``grt.eval`` package)
    get their new names, and keys added since (:data:`ADDED_DEFAULTS`, ``task.nominal_floor``) get the
    values those runs were made with.
    """
    data = copy.deepcopy(config)
    if version < FORMAT:
        data = _rename_targets(data)
        for key, value in ADDED_DEFAULTS.items():
            _set_absent(data, key, value)
        _set_absent(data, "task.nominal_floor", _floor(data))
    for key, value in ADDED_IN_FORMAT2.items():
        _set_absent(data, key, value)
    return data


def load_run_config(run_dir: str | Path) -> dict:
    """The red-team run's config as it ran, in the current format (see :func:`migrate`): plain data, a
    served policy's secret as given (``${oc.env:...}``), resolved where the config is made into a plan.

    Raises:
        ResumeError: ``run_dir`` is not a run folder.
    """
    run_dir = Path(run_dir)
    refuse_unless_run(run_dir)
    if (run_dir / RUN_CONFIG).is_file():
        record = read_yaml(run_dir / RUN_CONFIG)
        return migrate(record["config"], int(record.get(FORMAT_KEY, 1)))
    return migrate(read_yaml(run_dir / ".hydra" / "config.yaml"), 0)  # format 0: Hydra's record


def _rename_targets(node):
    if isinstance(node, dict):
        return {k: RENAMED_TARGETS.get(v, v) if k == "_target_" and isinstance(v, str) else _rename_targets(v)
                for k, v in node.items()}
    if isinstance(node, list):
        return [_rename_targets(v) for v in node]
    return node


def _set_absent(data: dict, key: str, value) -> None:
    """Set dotted ``key`` in ``data`` to ``value`` unless it is there (or its parent is not a mapping)."""
    if value is ABSENT:
        return
    *parents, last = key.split(".")
    for part in parents:
        data = data.get(part) if isinstance(data, dict) else None
        if not isinstance(data, dict):
            return
    if last not in data:
        data[last] = value


def _floor(data: dict):
    """What an absent ``task.nominal_floor`` means for the run's task (:data:`ABSENT`: leave it absent)."""
    task = data.get("task")
    if not isinstance(task, dict) or "nominal_floor" in task:
        return ABSENT
    try:
        return nominal_floor(task)
    except (ScoreConfigError, ValueError):  # a bad task.ci: the run reports it itself
        return ABSENT


def own_overrides(overrides: list[str]) -> list[str]:
    """A start's overrides but those no part of the run: ``resume=``, ``hydra.*``, the output folder."""
    return [o for o in overrides if not under(override_key(o), ("resume", "hydra", "paths.output_dir"))]


def under(key: str, prefixes: tuple[str, ...]) -> bool:
    """Whether ``key`` is one of ``prefixes`` or lies under one (``logger.mode``, ``hydra/launcher``)."""
    return any(key == p or key.startswith((f"{p}.", f"{p}/")) for p in prefixes)


# ------------------------------------------------------------------------------ what the user is told

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
        if reads_back(arg, key, value):
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
