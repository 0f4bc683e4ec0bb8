"""Checks of a composed config before anything is written: the first step of every Hydra app (:func:`validate`).

- the budget (:func:`grt.config.schema.check_budget`) and racing's need of a success rate;
- keys added on the command line with ``+`` that no code reads (:func:`check_added_keys`: ``+deformer.lamda=2``,
  ``+foo=1``) are refused with the section's keys and the close name, as ``+budget.foo=1`` is
  (:func:`grt.config.schema.unknown_budget_key`). A key added under a node with a ``_target_`` is an argument
  of its class (:func:`grt.targets.check_target` checks that the class takes it), and a few keys GRT reads
  when they are there may be left out of a YAML (:data:`READ_IF_GIVEN`: ``+task.ci=wilson``);
- the values of the plain sections a run uses (:func:`check_sections`: ``deformer``, ``mesh``, ``report``, the
  task's score settings), which their users would otherwise check only after the run folder's record is saved;
- the optimizer's settings, and every class a ``_target_`` names: it imports and takes the keys given to it.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterator, Mapping

from omegaconf import DictConfig, ListConfig, OmegaConf

from grt.config.schema import ConfigError, check_budget
from grt.errors import UserError
from grt.targets import build_error, check_target

#: Keys GRT reads from a section when they are given, that its YAMLs may leave out (so ``+key=`` adds them).
READ_IF_GIVEN: dict[str, tuple[str, ...]] = {
    "task": ("score_unit", "ci", "nominal_floor", "crash_margin", "manual"),
    "train": ("bc", "validation", "export", "overwrite_shipped", "seed", "freeze_normalization"),
}


class SettingError(UserError):
    """A key nothing reads, or a section's value out of range; the message names the key and the fix."""


def validate(cfg: DictConfig, classes: tuple[str, ...] | None = None) -> DictConfig:
    """Check a composed root config before anything is written; the first step of every Hydra app.

    Checks the budget (:func:`check_budget`), keys added with ``+`` that nothing reads
    (:func:`check_added_keys`; not for a resume, whose config was accepted when it started:
    its classes must import, their arguments are not checked again),
    the plain sections' values (:func:`check_sections`: ``deformer``, ``mesh``,
    ``report.videos``, the task's score settings), that the optimizer accepts its settings (CMA-ES needs a
    population of at least 2), and that every class the config names imports and takes the keys given to
    it (:func:`grt.targets.check_target`), so a bad value is refused before the run's folder is saved and
    before the nominal simulation.

    Args:
        cfg: the composed root config.
        classes: the config keys whose ``_target_`` this app builds (``("selector",)``; a task's session
            class imports the simulator); ``None``: every one.

    Returns:
        ``cfg``, unchanged.

    Raises:
        UserError: one line naming the key and the fix (exit code 2 in the CLIs, see :mod:`grt.cli._common`).
    """
    budget = cfg.get("budget")
    if budget is not None:
        check_budget(budget)
        _check_racing(budget, cfg.get("task"))
    added, groups, app = _command()
    resumed = bool(cfg.get("resume"))  # a run's own config, accepted when it started: its classes must import
    if added and not resumed:
        check_added_keys(cfg, added, app, groups)
    check_sections(cfg)
    optimizer = cfg.get("optimizer")
    if budget is not None and isinstance(optimizer, DictConfig) and "_target_" in optimizer:
        check_target("optimizer", optimizer)
        _check_optimizer(optimizer)
    for key, node in target_nodes(cfg):
        if classes is None or any(key == c or key.startswith(f"{c}.") for c in classes):
            check_target(key, node, arguments=not resumed)
    return cfg


def _command() -> tuple[list[str], set[str], str]:
    """The running Hydra app's overrides, config groups and name (``grt.run``); nothing outside an app."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return [], set(), "this command"
    hydra_cfg = HydraConfig.get()
    return list(hydra_cfg.overrides.task), set(hydra_cfg.runtime.choices), f"grt.{hydra_cfg.job.name}"


def _check_racing(budget: Mapping, task: Mapping | None) -> None:
    """Racing judges success rates (a hypergeometric count of failures): refuse it for a continuous score."""
    from grt.scores import ScoreSpec

    if budget.get("racing") and task is not None and not ScoreSpec.from_task(task).binary:
        spec = ScoreSpec.from_task(task)
        raise ConfigError(f"budget.racing=true needs a success rate, but task {task.get('name')}'s score is "
                          f"{spec.label}; run it with budget.racing=false")


def _check_optimizer(node: DictConfig) -> None:
    """Build the configured optimizer once (cheap, no simulation): its own range checks run now."""
    from hydra.utils import get_class, instantiate

    name = str(node._target_).rsplit(".", 1)[-1]
    least = getattr(get_class(str(node._target_)), "min_population", 1)
    population = node.get("population")
    if isinstance(population, int) and population < least:  # one line naming the setting, not the library's
        module = str(node._target_).rsplit(".", 2)[-2]
        why = getattr(get_class(str(node._target_)), "min_population_reason", "")
        raise ConfigError(f"budget.population={population} is too small for optimizer={module}: {name} needs a "
                          f"population of at least {least}{f' ({why})' if why else ''}; set "
                          f"budget.population={least} or more")
    try:
        instantiate(node)(num_handles=1)  # the optimizer groups are partials: num_handles comes at run time
    except UserError:
        raise
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{name} refuses its settings (optimizer.*, budget.population, budget.sigma): "
                          f"{exc}") from None
    except Exception as exc:  # noqa: BLE001 - a user's optimizer: one line, the traceback in a file
        raise build_error("optimizer", str(node._target_), "building it", exc) from None


def check_added_keys(cfg: DictConfig, overrides: list[str], app: str = "this command",
                     groups: set[str] | frozenset[str] = frozenset()) -> None:
    """Refuse keys added with ``+key=value`` that nothing reads (``++`` forces a value and is not checked).

    Args:
        cfg: the composed root config.
        overrides: the command's overrides (Hydra's ``overrides.task``).
        app: the command, for the message (``grt.run``).
        groups: the config groups of the command (``+experiment=NAME`` adds a group's option, not a key).

    Raises:
        SettingError: names the key, the keys of its section and the closest one.
    """
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(list(overrides))
    added = {o.key_or_group for o in parsed if o.is_add()}
    deleted = {o.key_or_group for o in parsed if o.is_delete()}
    for key in sorted(added):
        if key in groups or key == "hydra" or key.startswith(("hydra.", "hydra/", "budget.")) or "/" in key:
            continue  # Hydra's own settings; the budget's schema refuses its unknown keys itself
        _check_path(cfg, key, added, deleted, app)


def _check_path(cfg: DictConfig, key: str, added: set[str], deleted: set[str], app: str) -> None:
    parts = key.split(".")
    node = cfg
    for depth, name in enumerate(parts):
        if isinstance(node, DictConfig) and "_target_" in node:
            return  # an argument of a class (or inside one): the class's signature decides
        section = ".".join(parts[:depth])
        known = _known(node, section, added, deleted)
        if name not in known:
            raise SettingError(_unread(key, section, name, known, app))
        node = node._get_node(name) if isinstance(node, DictConfig) else None
        if not isinstance(node, DictConfig):
            return


def _known(node, section: str, added: set[str], deleted: set[str]) -> list[str]:
    """The keys of ``section`` something reads: those its YAML has (not only added by ``+``), those
    :data:`READ_IF_GIVEN` names, and a node deleted (``~key``) and given again."""
    names = set(READ_IF_GIVEN.get(section, ()))
    if isinstance(node, DictConfig):
        for name in node:
            path = f"{section}.{name}" if section else str(name)
            if path in deleted or not _created(node._get_node(name), path, added):
                names.add(str(name))
    return sorted(names)


def _created(node, path: str, added: set[str]) -> bool:
    """Whether the node at ``path`` exists only because ``+`` overrides added it (or keys under it)."""
    if path in added:
        return True
    if isinstance(node, DictConfig) and len(node) > 0 and "_target_" not in node:
        return all(_created(node._get_node(k), f"{path}.{k}", added) for k in node)
    return False


def _unread(key: str, section: str, name: str, known: list[str], app: str) -> str:
    where = section or app
    close = difflib.get_close_matches(name, known, n=1)
    hint = f"; did you mean {f'{section}.' if section else ''}{close[0]}?" if close else ""
    keys = f"{where}'s keys are {', '.join(known)}" if known else f"{where} has no keys of its own"
    return f"+{key}: nothing reads {key} (added with '+', it would be stored and never used); {keys}{hint}"


def check_sections(cfg: DictConfig) -> None:
    """Check the plain sections' values that are cheap to check, before anything is written: ``deformer``
    (method, lam, radius, validity, max_volume_change), ``mesh`` (:class:`grt.geometry.prepare.MeshSettings`),
    ``report.videos``, ``swap_check`` (:class:`grt.agreement.SwapCheckSettings`) and the task's score settings
    (``task.ci``, ``task.nominal_floor``, ``task.crash_margin``).

    Raises:
        UserError: one line naming the key and what it accepts.
    """
    check_resolves(cfg)
    check_task_session(cfg.get("task"))
    deformer = cfg.get("deformer")
    if isinstance(deformer, DictConfig):
        check_deformer(deformer)
    if "mesh" in cfg:
        from grt.geometry.prepare import MeshSettings

        MeshSettings.from_config(cfg.get("mesh"))
    videos = OmegaConf.select(cfg, "report.videos", default=0)
    if not (isinstance(videos, int) and not isinstance(videos, bool) and videos >= 0):
        raise SettingError(f"report.videos={videos!r}: give an integer >= 0 (CrashShapes filmed; 0: none)")
    if "swap_check" in cfg:
        from grt.agreement import SwapCheckSettings

        SwapCheckSettings.from_config(cfg.get("swap_check"))
    task = cfg.get("task")
    if isinstance(task, DictConfig) and "score" in task:
        from grt.scores import ScoreSpec, crash_margin, nominal_floor

        ScoreSpec.from_task(task)
        nominal_floor(task)
        crash_margin(task)


def check_resolves(cfg: DictConfig) -> None:
    """Refuse a config whose ``${...}`` interpolations read a key it does not have (a task YAML without the
    ``env_id`` its ``session.env_id: ${..env_id}`` reads), before anything is built or written.

    Raises:
        SettingError: names the key, what it reads, and the key to add.
    """
    from omegaconf.errors import InterpolationKeyError, InterpolationResolutionError

    for section in cfg:
        node = cfg._get_node(section)
        if not OmegaConf.is_config(node):
            continue
        try:
            OmegaConf.to_container(node, resolve=True)
        except InterpolationKeyError as exc:
            raise _missing(cfg, exc) from None
        except InterpolationResolutionError:  # a resolver that needs Hydra's app (${hydra:...}): not this check's
            continue


def _missing(cfg: DictConfig, exc: Exception) -> SettingError:
    """The error for the interpolation of ``exc`` that reads a key ``cfg`` does not have."""
    key = str(getattr(exc, "full_key", "") or "")
    parent, _, name = key.rpartition(".")
    node = OmegaConf.select(cfg, parent) if parent else cfg
    raw = node._get_node(name)._value() if isinstance(node, DictConfig) and name in node else None
    reads = f" ({key}: {raw})" if raw is not None else ""
    missing = _absolute(key, str(raw)) if isinstance(raw, str) else None
    fix = (f"add {missing.rpartition('.')[2]}: to the {missing.partition('.')[0]} config (or give "
           f"{missing}=VALUE)" if missing else "give the key it reads")
    return SettingError(f"{key} reads a setting the config does not have{reads}: {str(exc).splitlines()[0]}; {fix}")


def _absolute(key: str, interpolation: str) -> str | None:
    """The full key a relative interpolation ``${..env_id}`` at ``key`` reads (``task.env_id``), or ``None``."""
    if not (interpolation.startswith("${.") and interpolation.endswith("}")):
        return None
    body = interpolation[2:-1]
    dots = len(body) - len(body.lstrip("."))
    parts = key.split(".")[:-1]
    return ".".join([*parts[: len(parts) - (dots - 1)], body[dots:]]) if dots - 1 <= len(parts) else None


def check_task_session(task) -> None:
    """A task config whose ``session`` names no class (``_target_`` left out of a user's task YAML).

    Raises:
        SettingError: names the key and the session class of a ManiSkill task.
    """
    session = task.get("session") if isinstance(task, DictConfig) else None
    if isinstance(session, DictConfig) and "_target_" not in session:
        raise SettingError(f"task.session of task {task.get('name')!r} has no _target_: name the session class "
                           "in the task YAML (a ManiSkill task: _target_: "
                           "grt.tasks.maniskill.session.ManiSkillSession)")


def check_deformer(node) -> None:
    """Refuse ``deformer.*`` values :class:`grt.geometry.deform.ShapeDeformer` or the validity check would
    refuse (or misread) only after the run's record is saved.

    Raises:
        SettingError: names the key, the value and what it accepts.
    """
    from grt.geometry.deform import METHODS

    method = node.get("method", "exact")
    if method not in METHODS:
        raise SettingError(f"deformer.method={method!r}: use one of {', '.join(METHODS)}")
    for key, low, high, accepts in (("lam", 0, math.inf, "a number > 0 (the anchors' weight)"),
                                    ("radius", 0, 1, "a number in (0, 1] (a fraction of the bounding-box "
                                     "diagonal)")):
        value = node.get(key, 1.0)
        if not _number(value) or not low < value <= high:
            raise SettingError(f"deformer.{key}={value!r}: give {accepts}")
    validity = node.get("validity", True)
    if not isinstance(validity, bool):
        raise SettingError(f"deformer.validity={validity!r}: give true (check every candidate for "
                           "self-intersections and folds) or false")
    bound = node.get("max_volume_change")
    if bound is not None and (not _number(bound) or not bound > 0):
        raise SettingError(f"deformer.max_volume_change={bound!r}: give a number > 0 (a fraction of the volume) "
                           "or null (not checked)")


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def target_nodes(cfg, path: str = "") -> Iterator[tuple[str, DictConfig]]:
    """``(key, node)`` of every node with a ``_target_`` in ``cfg`` (Hydra's own ``hydra`` node left out),
    outermost first; ``key`` is the dotted path (``policy``, ``task.session``, ``train.bc.expert``)."""
    if isinstance(cfg, DictConfig):
        if "_target_" in cfg:
            yield path, cfg
        for key in cfg:
            if path == "" and key == "hydra":
                continue
            child = cfg._get_node(key)
            if isinstance(child, (DictConfig, ListConfig)) and not child._is_missing() and not child._is_none():
                yield from target_nodes(child, f"{path}.{key}" if path else str(key))
    elif isinstance(cfg, ListConfig):
        for i, child in enumerate(cfg._iter_ex(resolve=False)):
            if isinstance(child, (DictConfig, ListConfig)):
                yield from target_nodes(child, f"{path}[{i}]")
