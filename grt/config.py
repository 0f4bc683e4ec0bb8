"""Typed config schemas, their validation, and OmegaConf resolvers, registered before Hydra composes.

The ``budget`` group is validated by a dataclass schema, so a misspelled key (``budget.trails=3``) or a
value of the wrong type (``budget.trials=abc``) fails when the config is composed, with the key's name in
the message. Ranges (``budget.trials=0``) and keys added with ``+`` (``+budget.popsize=3``, which no code
would read) are refused by :func:`validate`, which each Hydra app calls on its first line, before any
simulation. Groups with a ``_target_`` are checked by the class signature at instantiation (an unknown
key names itself in the TypeError).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import omegaconf
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from grt.errors import UserError
from grt.settings import check_added_keys, check_sections
from grt.targets import build_error, check_target, targets


class ConfigError(UserError):
    """A config value out of range or a key no schema knows; the message names the key and the fix."""


@dataclass(frozen=True)
class Rule:
    """What one config value accepts: ``check(value) -> bool``, described by ``accepts`` in messages."""

    accepts: str
    check: Callable[[Any], bool]


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def at_least(low: int) -> Rule:
    return Rule(f"an integer >= {low}", lambda v: _is_int(v) and v >= low)


POSITIVE = Rule("a finite number > 0", _is_positive)
POSITIVE_OR_NULL = Rule("null (off) or a finite number > 0", lambda v: v is None or _is_positive(v))
BOOLEAN = Rule("true or false", lambda v: isinstance(v, bool))
RISK = Rule("a number in [0, 0.5) (0: only stop a candidate that cannot matter even if every trial left fails)",
            lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < 0.5)


def _field(default, rule: Rule, meaning: str):
    return field(default=default, metadata={"rule": rule, "meaning": meaning})


@dataclass
class BudgetSchema:
    """The numbers of a search (paper appendix, lines 1062-1099); each field's ``Rule`` is in its metadata.

    Attributes:
        population: candidates per iteration (paper: 10).
        iterations: ``T`` (paper: 10).
        trials: simulated episodes per candidate (paper: 64 for grasping).
        sigma: std of the Gaussian over handle displacements, unit-cube units (paper: 0.001).
        seed: seeds the optimizer and the episode seeds (paper: 42).
        workers: simulator worker processes.
        tau: Smoothness-Score budget in meters (``None``: off, or ``tau_rel``'s).
        tau_rel: the budget relative to the object: a fraction of its bounding-box diagonal, converted to
            meters per object (:func:`grt.optimizers.smoothness.budget_tau`); used when ``tau`` is ``None``.
        top_k: CrashShapes saved in the run folder.
        confirm_trials: fresh episodes on which the nominal object and each CrashShape are scored again
            after the search, with a paired test of each drop (:mod:`grt.confirm`); 0 turns it off.
        videos: CrashShapes whose failing trial (and the nominal object's on the same seed) are filmed
            for ``report.html`` after the search (:mod:`grt.rerun`); 0 turns it off. ``report.videos``
            of ``conf/run.yaml`` reads it.
        racing: run each candidate's trials in rounds and stop it once it cannot be a CrashShape among the
            ``top_k`` (:mod:`grt.racing`); off: every candidate runs every trial (as before racing existed).
        race_rounds: rounds of about equal size a raced candidate's trials run in (at most one per trial).
        race_alpha: the most probability with which racing stops a candidate that would have mattered.
    """

    population: int = _field(10, at_least(1), "candidates per iteration")
    iterations: int = _field(10, at_least(1), "search iterations T")
    trials: int = _field(64, at_least(1), "simulated episodes per candidate")
    sigma: float = _field(0.001, POSITIVE, "std of the handle displacements, unit-cube units")
    seed: int = _field(42, at_least(0), "seed of the optimizer and of the episode seeds")
    workers: int = _field(2, at_least(1), "simulator worker processes")
    tau: float | None = _field(None, POSITIVE_OR_NULL, "Smoothness-Score budget in meters")
    tau_rel: float | None = _field(None, POSITIVE_OR_NULL, "Smoothness-Score budget as a fraction of the object's "
                                   "bounding-box diagonal (used when budget.tau is null)")
    top_k: int = _field(3, at_least(1), "CrashShapes saved in the run folder")
    confirm_trials: int = _field(0, at_least(0), "fresh episodes re-scoring the nominal object and each "
                                 "CrashShape after the search (0: off)")
    videos: int = _field(3, at_least(0), "CrashShapes filmed for report.html after the search (0: off)")
    racing: bool = _field(False, BOOLEAN, "race each candidate's trials in rounds, stopping one that cannot matter")
    race_rounds: int = _field(8, at_least(2), "rounds a raced candidate's trials run in")
    race_alpha: float = _field(0.05, RISK, "the most probability of stopping a candidate that would have mattered")


BUDGET_KEYS = tuple(f.name for f in fields(BudgetSchema))


def check_budget(budget: Mapping) -> None:
    """Refuse a budget with a key :class:`BudgetSchema` lacks or a value out of its field's range.

    Raises:
        ConfigError: names the key, the value given and what the key accepts.
    """
    unknown = sorted(set(budget) - set(BUDGET_KEYS))
    if unknown:
        raise ConfigError(unknown_budget_key(unknown[0]))
    for f in fields(BudgetSchema):
        rule, key = f.metadata["rule"], f"budget.{f.name}"
        if f.name not in budget or (isinstance(budget, DictConfig) and OmegaConf.is_missing(budget, f.name)):
            raise ConfigError(f"{key} is not set; give {rule.accepts} ({f.metadata['meaning']}): {key}=...")
        try:
            value = budget[f.name]
        except OmegaConfBaseException as exc:  # e.g. trials: ${task.trials} resolving to a wrong type
            raise ConfigError(f"{key}: {str(exc).splitlines()[0]}; it must be {rule.accepts}") from None
        if not rule.check(value):
            raise ConfigError(f"{key}={value!r} is out of range: it must be {rule.accepts} "
                              f"({f.metadata['meaning']})")


def unknown_budget_key(name: str) -> str:
    """The message for a key the budget does not have (``budget.trails=3``, ``+budget.popsize=3``)."""
    return (f"budget.{name} is not a budget setting (with '+' it would be added and never read); "
            f"the budget's keys are {', '.join(BUDGET_KEYS)}")


def budget_hint(full_key: str) -> str | None:
    """What ``budget.<key>`` accepts, for messages about it (``None`` for other keys)."""
    name = full_key.split(".", 1)[1] if full_key.startswith("budget.") else ""
    meta = {f.name: f.metadata for f in fields(BudgetSchema)}.get(name)
    return f"{full_key} must be {meta['rule'].accepts} ({meta['meaning']})" if meta else None


def validate(cfg: DictConfig, classes: tuple[str, ...] | None = None) -> DictConfig:
    """Check a composed root config before anything is written; the first step of every Hydra app.

    Checks the budget (:func:`check_budget`), keys added with ``+`` that nothing reads
    (:func:`grt.settings.check_added_keys`; not for a resume, whose config was accepted when it started:
    its classes must import, their arguments are not checked again),
    the plain sections' values (:func:`grt.settings.check_sections`: ``deformer``, ``mesh``,
    ``report.videos``, the task's score settings), that the optimizer accepts its settings (CMA-ES needs a
    population of at least 2), and that every class the config names imports and takes the keys given to
    it (:func:`grt.targets.check_targets`), so a bad value is refused before the run's folder is saved and
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
    for key, node in targets(cfg):
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


def plain(node) -> dict | list:
    """A config node as plain Python containers, interpolations resolved (what library code takes)."""
    return OmegaConf.to_container(node, resolve=True)


def object_name(spec: str) -> str:
    """A short name for an object spec: the built-in name, or a file's stem."""
    text = str(spec)
    return Path(text).stem if ("/" in text or "." in text) else text


def object_folder(spec: str) -> str:
    """The folder name of an object spec in run folders' paths: a built-in's name (``mug``), a mesh file's
    name with its suffix (``mug.obj``; ``mug-file`` for a file without one), so the runs of a user's mesh
    named like a built-in never land beside the built-in's."""
    text = str(spec)
    if not ("/" in text or "." in text):
        return text
    name = Path(text).name or text.strip("/").replace("/", "_")
    return name if Path(name).suffix else f"{name}-file"


_OMEGACONF_24 = tuple(int(p) for p in omegaconf.__version__.split(".")[:2]) >= (2, 4)


def add_resolver(name: str, resolver: Callable[..., Any]) -> None:
    """Register an OmegaConf resolver once (idempotent), under the name each OmegaConf version wants.

    OmegaConf 2.4 renamed ``register_new_resolver`` to ``register_resolver`` and warns on the old
    name; the warning would land on the stderr of every command, one-line errors included.
    """
    if OmegaConf.has_resolver(name):
        return
    if _OMEGACONF_24:  # before 2.4, register_resolver is the legacy strings-only API
        OmegaConf.register_resolver(name, resolver, annotation_validation="off")
    else:
        OmegaConf.register_new_resolver(name, resolver)


def register() -> None:
    """Register schemas and resolvers (idempotent); ``resume_or`` is :mod:`grt.runfolder`'s."""
    cs = ConfigStore.instance()
    cs.store(group="budget", name="schema", node=BudgetSchema)
    add_resolver("object_name", object_name)
    add_resolver("object_folder", object_folder)
    # the installed package's folder (shipped checkpoints live under it), wherever GRT runs from
    add_resolver("grt_dir", lambda: str(Path(__file__).resolve().parent))


register()
