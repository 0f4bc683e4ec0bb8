"""Resuming a run folder: what ``resume=DIR`` may change, and the config the resumed work goes on with.

``resume=DIR`` alone is the whole command to continue a red-team run: :func:`resume_overrides` checks DIR
and the command before Hydra starts, so a refused resume writes nothing anywhere, and hands Hydra the run's
own overrides; :func:`own_config` then gives the app the saved config. With ``resume=`` only the
:data:`RESUME_FREE` keys may be given (they do not change the search); any other key must keep the run's
own value. A training folder (``python -m grt.train``) is resumed the same way (:data:`TRAINING`):
:data:`TRAIN_FREE` are the keys a resume may give and :func:`own_training_config` gives the app the recorded
config; a blue-team study (``python -m grt.blueteam``) likewise (:data:`STUDY`, :data:`STUDY_FREE`,
:func:`own_study_config`).

Everything here is plain data: configs are mappings (the app turns the result into Hydra's config), the
command line is :class:`grt.config.records.Override` values.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from grt.config.records import ConfigView, Override, parse_overrides, read_yaml
from grt.plan import dotted
from grt.runfolder.record import (
    ABSENT,
    FORMAT,
    RUN_CONFIG,
    STUDY_RECORD,
    TRAIN_RECORD,
    ResumeError,
    hydra_record,
    is_study_folder,
    is_training_folder,
    migrate,
    override_key,
    own_overrides,
    read_record,
    refuse_unless_profile,
    refuse_unless_run,
    refuse_unless_study,
    refuse_unless_training,
    under,
)

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
# A blue-team study (``python -m grt.blueteam``): the keys a resume may set, none of which changes the study
# (its red-team run, CrashShapes, held-out shapes, episode seeds, PPO settings, guard and confirmation):
# workers only says which process steps an env (each env is seeded by its index) and how many evaluate,
# blueteam.iterations and blueteam.val_patience only where a fine-tune not yet finished stops (a finished
# one, policy.pt written, is not trained again), blueteam.rered.enabled whether a re-red-team follows the
# table, the evaluator's backend and workers give the same results (its collision keys stay the study's),
# and the collision cache and Hydra's files only record. With the evaluator's free keys (``_evaluator_free``).
STUDY_FREE = ("workers", "blueteam.iterations", "blueteam.val_patience", "blueteam.rered.enabled",
              "paths.cache_dir", "hydra")
# The parts of a resumed study's config taken from the command (and the evaluator but its collision keys),
# and those taken from it only when it gives them (else the record's, whatever today's defaults).
STUDY_FROM_COMMAND = ("workers", "paths")
STUDY_WHEN_GIVEN = ("blueteam.iterations", "blueteam.val_patience", "blueteam.rered.enabled")
# A robustness profile (``python -m grt.profile``): the keys a resume may set (where its trials run, the
# collision cache, Hydra's files), with the evaluator's free keys; its shapes and episodes are its record's.
PROFILE_FREE = ("budget.workers", "paths.cache_dir", "hydra")


@dataclass
class SavedRun:
    """A run's own start, as its folder records it.

    Attributes:
        overrides: its command line's overrides (``resume=``, ``hydra.*`` and ``paths.output_dir`` left out).
        choices: its config-group options, e.g. ``{"selector": "all"}``.
        config: its config (resolved; Hydra's record for a format-0 folder), migrated to the current format,
            as plain data (interpolations as written).
        format: the folder's format (see :mod:`grt.runfolder.record`).
        started: whether the record is of the start (``False``: a training's or study's folder whose ``.hydra``
            a resume rewrote, before ``grt.train`` / ``grt.blueteam`` kept the start's record: the record of
            its latest resume).
    """

    overrides: list[str]
    choices: dict
    config: dict
    format: int = FORMAT
    started: bool = True

    @classmethod
    def load(cls, run_dir: Path) -> SavedRun:
        """Read ``run_dir``; a missing folder or one that is not a run raises :class:`ResumeError`."""
        refuse_unless_run(run_dir)
        try:
            version, overrides, choices, config = read_record(run_dir)
            config = migrate(config, version)
            own, choices = own_overrides(overrides), _own_choices(choices)
        except Exception as exc:  # noqa: BLE001 - any unreadable record is the same user error
            raise ResumeError(f"resume={run_dir}: its record of the run cannot be read ({exc}); "
                              "start a new run") from None
        return cls(own, choices, config, version)

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
            overrides, choices, config = hydra_record(run_dir)
            own, choices = own_overrides(overrides), _own_choices(choices)
            started = config.get("resume") is None  # a resume's record names the folder it resumed
        except Exception as exc:  # noqa: BLE001 - any unreadable record is the same user error
            raise ResumeError(f"resume={run_dir}: its record of the {noun} ({TRAIN_RECORD} and the files "
                              f"beside it) cannot be read ({exc}); start a new {noun}") from None
        return cls(own, choices, config, 0, started)

    def value(self, key: str):
        """The run's option of group ``key``, or its value of config key ``key`` (:data:`ABSENT`: none)."""
        if key in self.choices:
            return self.choices[key]
        return ConfigView(self.config).get(key, default=ABSENT, resolve=False)

    def keeps(self, override: Override) -> bool:
        """Whether ``override`` gives the run's own value (so it changes nothing)."""
        if override.sweep:
            return False
        have = self.value(override.key)
        if override.delete:
            return have is ABSENT
        return have is not ABSENT and have == override.value


def _own_choices(choices: dict) -> dict:
    return {k: v for k, v in choices.items() if not under(k, ("hydra",))}


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


def _evaluator_free(key: str) -> bool:
    """Whether a resume may give ``key``: the evaluator group (``evaluator=ray``) or one of its keys that do
    not shape results (:data:`EVALUATOR_RESULTS`)."""
    if key == "evaluator":
        return True
    return key.startswith("evaluator.") and not under(key.removeprefix("evaluator."), EVALUATOR_RESULTS)


# A red-team run (python -m grt.run) and a training (python -m grt.train).
RUN = Resumable(SavedRun.load, lambda key: under(key, RESUME_FREE) or _evaluator_free(key), "run", RUN_CONFIG,
                f"{', '.join(RESUME_FREE)}.*, evaluator=sim|ray and the evaluator's keys but "
                f"{', '.join(EVALUATOR_RESULTS)}")
TRAINING = Resumable(SavedRun.training, lambda key: under(key, TRAIN_FREE), "training", TRAIN_RECORD,
                     f"{', '.join(TRAIN_FREE)}.*")
# A robustness profile (python -m grt.profile).
PROFILE = Resumable(SavedRun.profile, lambda key: under(key, PROFILE_FREE) or _evaluator_free(key), "profile",
                    TRAIN_RECORD, f"{', '.join(PROFILE_FREE)}.*, evaluator=sim|ray and the evaluator's keys but "
                    f"{', '.join(EVALUATOR_RESULTS)}")
# A blue-team study (python -m grt.blueteam).
STUDY = Resumable(SavedRun.study, lambda key: under(key, STUDY_FREE) or _evaluator_free(key), "study", STUDY_RECORD,
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
        ``overrides`` unchanged without ``resume=`` (or with a malformed override, which Hydra reports).

    Raises:
        ResumeError: DIR is missing or not a run (of ``kind``), empty (``resume=`` of an unset shell variable;
            ``resume=null`` is no resume), or an override would change the run (names the keys).
    """
    given = parse_overrides(overrides)
    if given is None:
        return overrides  # Hydra reports a malformed override itself
    resume = [o for o in given if o.key == "resume"]
    if resume and isinstance(resume[-1].value, str) and not resume[-1].value.strip():
        raise ResumeError(f"{resume[-1].line.strip()!r}: resume= is empty (an unset shell variable?), and a "
                          f"new {kind.noun} is not what resume= asks for: give the folder to continue "
                          f"(resume=DIR), or leave resume= out to start a new {kind.noun}")
    if not resume or not resume[-1].value:
        return overrides
    run_dir = resume[-1].value
    if not isinstance(run_dir, str):
        raise ResumeError(f"{resume[-1].line}: resume= takes one run folder")
    saved = kind.load(Path(run_dir))
    if kind is RUN:
        refuse_edited_record(Path(run_dir))
    free = [o for o in given if kind.free(o.key)]
    changed = [o for o in given if o.key != "resume" and o not in free and not saved.keeps(o)]
    if changed:
        what = ", ".join(f"{o.key} (the {kind.noun}'s: {_shown_value(saved.value(o.key))}, "
                         f"given: {o.line.partition('=')[2] or 'deleted'})" for o in changed)
        raise ResumeError(
            f"resume={run_dir}: {what} would change the {kind.noun}, which keeps its own config ({kind.record} "
            f"there). Continue it with resume={run_dir} alone (allowed with it: {kind.allowed}), "
            f"or start a new {kind.noun} with these settings: the same command without resume=")
    own = [line for line in saved.overrides if not any(under(override_key(line), (o.key,)) for o in free)]
    return [*own, "hydra.output_subdir=.hydra/resume", *(o.line for o in free), resume[-1].line]


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
        saved, started = read_yaml(record)["config"], read_yaml(start)
        view = ConfigView(started)
    except Exception:  # noqa: BLE001 - an unreadable record: SavedRun.load names it
        return []
    found: list[str] = []
    _compare(ConfigView(saved), saved, started, view, "", found)
    evaluator = saved.get("evaluator") if isinstance(saved.get("evaluator"), dict) else {}
    for key in EVALUATOR_RESULTS:
        if key in evaluator:
            _compare_leaf(ConfigView(saved).get(f"evaluator.{key}"), view, f"evaluator.{key}", found)
    return found


def _compare(mine: ConfigView, saved: dict, node, started: ConfigView, prefix: str, found: list[str]) -> None:
    for key in saved:
        path = f"{prefix}{key}"
        if under(path, _NOT_COMPARED) or not isinstance(node, dict) or key not in node:
            continue
        if isinstance(saved[key], dict) and isinstance(node[key], dict):
            _compare(mine, saved[key], node[key], started, f"{path}.", found)
        else:
            _compare_leaf(mine.get(path), started, path, found)


def _compare_leaf(value, started: ConfigView, path: str, found: list[str]) -> None:
    try:
        had = started.resolve(path)
    except Exception:  # noqa: BLE001 - e.g. ${hydra:...}: nothing to compare with outside the run
        return
    if value != had:
        found.append(f"{path} ({RUN_CONFIG}: {value}, {TRAIN_RECORD}: {had})")


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


def own_config(resume: str, command: Mapping) -> dict | None:
    """A resumed run's config: its saved one, with the :data:`FROM_COMMAND` parts of this command.

    Args:
        resume: the run's folder (``resume=``).
        command: this command's config, composed from the run's own overrides (:func:`resume_overrides`),
            resolved.

    Returns:
        The config, or ``None`` for a format-0 folder, which has no resolved record of its config: the
        command's, composed from the run's own overrides, is its config.

    Raises:
        ResumeError: the command would simulate on another physics than the run's (a GPU's or the CPU's).
    """
    saved = SavedRun.load(Path(resume))
    if saved.format == 0:
        return None
    own = copy.deepcopy(saved.config)
    for key in FROM_COMMAND:
        value = dotted(command, key, ABSENT)
        if value is not ABSENT and (dotted(own, key, ABSENT) is not ABSENT or key in AFTER_SEARCH):
            _set(own, key, value)
    if isinstance(command.get("evaluator"), Mapping):  # the backend of this command, the run's collision geometry
        evaluator, saved_ev = copy.deepcopy(dict(command["evaluator"])), own.get("evaluator") or {}
        evaluator.update({k: saved_ev[k] for k in EVALUATOR_RESULTS if k in saved_ev})
        if _on_gpu(saved_ev) != _on_gpu(evaluator):  # the GPU's physics is not the CPU's: one journal, one
            was, now = ("evaluator=gpu", "CPU workers") if _on_gpu(saved_ev) else ("CPU workers", "evaluator=gpu")
            raise ResumeError(f"resume={resume}: the run's trials were simulated with {was}, this command would "
                              f"go on with {now}, whose physics differs: resume it with "
                              f"{'evaluator=gpu' if _on_gpu(saved_ev) else 'evaluator=sim or evaluator=ray'}")
        own["evaluator"] = evaluator
    own["resume"] = resume
    return own


def _on_gpu(evaluator) -> bool:
    """Whether an evaluator config simulates on a GPU (``evaluator=gpu`` on ``physx_cuda``; on ``physx_cpu``
    its trials are the CPU workers' bit for bit)."""
    return str(evaluator.get("_target_", "")).endswith(".GpuEvaluator") and evaluator.get("backend") != "physx_cpu"


def own_training_config(resume: str, command: Mapping) -> dict:
    """A resumed training's config: its record (``DIR/.hydra/config.yaml``, as composed at its start, its
    interpolations kept), with the :data:`TRAIN_FROM_COMMAND` parts of ``command`` (this command's config,
    resolved: composed by Hydra from the training's own overrides and the free ones,
    :func:`resume_overrides`)."""
    own = copy.deepcopy(SavedRun.training(Path(resume)).config)
    for key in TRAIN_FROM_COMMAND:
        value = dotted(command, key, ABSENT)
        if value is not ABSENT:
            _set(own, key, value)
    own["resume"] = resume
    return own


def own_study_config(resume: str, command: Mapping, overrides: list[str]) -> dict:
    """A resumed blue-team study's config: its record (``DIR/.hydra/config.yaml``, as composed at its start,
    its interpolations kept), with the :data:`STUDY_FROM_COMMAND` parts of ``command`` (this command's
    config, resolved), the :data:`STUDY_WHEN_GIVEN` ones its ``overrides`` set, and this command's evaluator
    but the study's collision keys (:data:`EVALUATOR_RESULTS`)."""
    own = copy.deepcopy(SavedRun.study(Path(resume)).config)
    given = {override_key(o) for o in overrides}
    for key in (*STUDY_FROM_COMMAND, *(k for k in STUDY_WHEN_GIVEN if k in given)):
        value = dotted(command, key, ABSENT)
        if value is not ABSENT:
            _set(own, key, value)
    if isinstance(command.get("evaluator"), Mapping):
        evaluator, saved_ev = copy.deepcopy(dict(command["evaluator"])), own.get("evaluator") or {}
        evaluator.update({k: saved_ev[k] for k in EVALUATOR_RESULTS if k in saved_ev})
        own["evaluator"] = evaluator
    own["resume"] = resume
    return own


def check_in_place(run_dir: Path, config: Mapping, app: str) -> None:
    """Refuse a ``grt.train`` (``grt.blueteam``) command without ``resume=`` whose ``hydra.run.dir`` holds a
    training (a study) started with other settings: continued in place, it would go on from that folder's
    ``last.pt`` with this command's settings and write Hydra's record of them over the record of its start.
    The same command again (a requeued job), or one that changes only what a resume may change, goes on.

    Args:
        config: this command's config as composed (interpolations as written).

    Raises:
        ResumeError: names the settings that differ and the two ways on (``resume=DIR``, another folder).
    """
    if config.get("resume"):
        return
    if app == "train" and is_training_folder(run_dir):
        noun, free, command = "training", lambda key: under(key, TRAIN_FREE), "python -m grt.train"
    elif app == "blueteam" and is_study_folder(run_dir):
        noun, free, command = "study", lambda key: under(key, STUDY_FREE) or _evaluator_free(key), \
            "python -m grt.blueteam"
    else:
        return
    try:
        saved = _leaves(read_yaml(run_dir / ".hydra" / "config.yaml"))
    except Exception:  # noqa: BLE001 - an unreadable record: the app's own resume checks name it
        return
    now = _leaves(config)
    changed = sorted(k for k in set(saved) | set(now) if not free(k) and k != "resume"
                     and saved.get(k, ABSENT) != now.get(k, ABSENT))
    changed = [k for k in changed if not any(k.startswith(f"{c}.") for c in changed)]  # train.bc, not its keys
    if not changed:
        return

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
    for key, value in (node.items() if isinstance(node, Mapping) else ()):
        path = f"{prefix}{key}"
        if path == "hydra":
            continue
        if isinstance(value, Mapping) and value:
            out.update(_leaves(value, f"{path}."))
        else:
            out[path] = value
    return out


def _set(config: dict, key: str, value) -> None:
    """Set dotted ``key`` of a plain config to (a copy of) ``value``, making the mappings on its way."""
    *parents, last = key.split(".")
    for part in parents:
        if not isinstance(config.get(part), dict):
            config[part] = {}
        config = config[part]
    config[last] = copy.deepcopy(value)


def _shown_value(value) -> str:
    return "unset" if value is ABSENT else str(value)
