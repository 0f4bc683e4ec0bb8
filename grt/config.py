"""Typed config schemas, their validation, and OmegaConf resolvers, registered before Hydra composes.

The ``budget`` group is validated by a dataclass schema, so a misspelled key (``budget.trails=3``) or a
value of the wrong type (``budget.trials=abc``) fails when the config is composed, with the key's name in
the message. Ranges (``budget.trials=0``) and keys added with ``+`` (``+budget.popsize=3``, which no code
would read) are refused by :func:`validate`, which each Hydra app calls on its first line, before any
simulation. Groups with a ``_target_`` are checked by the class signature at instantiation (an unknown
key names itself in the TypeError).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import field, fields, make_dataclass
from pathlib import Path
from typing import Any, get_type_hints

import omegaconf
from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from grt import motionplanning_dir
from grt.agreement import SwapCheckSettings
from grt.errors import UserError
from grt.geometry.prepare import MeshSettings
from grt.plan import (  # noqa: F401 - the rules' vocabulary, re-exported for the apps' own settings
    BOOLEAN,
    BUDGET_KEYS,
    POSITIVE,
    POSITIVE_OR_NULL,
    RISK,
    Budget,
    DeformerPlan,
    Rule,
    RunPlan,
    at_least,
    object_folder,
    object_name,
)
from grt.settings import check_added_keys, check_sections
from grt.targets import build_error, check_target, targets


class ConfigError(UserError):
    """A config value out of range or a key no schema knows; the message names the key and the fix."""


#: The ``budget`` group's schema: :class:`grt.plan.Budget`'s fields (defaults, rules, meanings), as the
#: mutable dataclass Hydra composes into (a frozen one would refuse the presets and overrides).
BudgetSchema = make_dataclass(
    "BudgetSchema", [(f.name, get_type_hints(Budget)[f.name], field(default=f.default, metadata=f.metadata))
                     for f in fields(Budget)],
    namespace={"__doc__": Budget.__doc__, "__module__": __name__})


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


def make_plan(cfg, choices: Mapping | None = None) -> RunPlan:
    """The plan of one red-team run: its config parsed once (:mod:`grt.plan`).

    Args:
        cfg: the composed root config of ``grt.run``, or a run folder's saved config (a plain mapping).
        choices: the run's config-group options; by default the running Hydra app's, else each group's
            ``_target_`` module name (a test calling :func:`grt.runner.run` without Hydra).

    Raises:
        ScoreConfigError: a bad ``task.ci``, ``task.nominal_floor`` or ``task.crash_margin``.
    """
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    score, floor, margin = RunPlan.task_settings(cfg.task)
    return RunPlan(
        run_dir=Path(cfg.resume or cfg.paths.output_dir), resume=bool(cfg.resume), object=str(cfg.object),
        object_scale=float(cfg.get("object_scale", 1.0) or 1.0),
        cache_dir=str(OmegaConf.select(cfg, "paths.cache_dir", default="~/.cache/grt")),
        mesh=MeshSettings.from_config(cfg.get("mesh")), task=plain(cfg.task), policy=plain(cfg.policy),
        **{key: plain(cfg[key]) if cfg.get(key) is not None else {} for key in _BUILT},
        deformer=DeformerPlan.of(cfg.get("deformer") or {}), budget=Budget.of(cfg.budget), score=score,
        nominal_floor=floor, crash_margin=margin,
        report_videos=int(OmegaConf.select(cfg, "report.videos", default=0) or 0),
        swap_check=SwapCheckSettings.from_config(plain(cfg.swap_check) if cfg.get("swap_check") is not None else None),
        choices=dict(choices) if choices is not None else _choices(cfg), config=without_secrets(cfg),
        record=_command_line())


#: The ``_target_`` nodes a run builds at run time (selector, optimizer, evaluator, logger).
_BUILT = ("selector", "optimizer", "evaluator", "logger")


def _choices(cfg: DictConfig) -> dict:
    """The config-group options of a run: the running Hydra app's, else (no Hydra) each built group's and the
    policy's ``_target_`` module name, which is the option's by convention."""
    from hydra.core.hydra_config import HydraConfig

    found = {str(k): v for k, v in plain(HydraConfig.get().runtime.choices).items()
             if not (k == "hydra" or str(k).startswith("hydra/"))} if HydraConfig.initialized() else {}
    for group in (*_BUILT, "policy"):
        if group not in found and isinstance(cfg.get(group), DictConfig) and "_target_" in cfg[group]:
            found[group] = str(cfg[group]["_target_"]).rsplit(".", 2)[-2]
    return found


def _command_line() -> dict:
    """The running Hydra app's command line as a run's record keeps it: its overrides (``resume=`` left out)
    and its config-group options (``hydra/*`` left out); empty outside Hydra."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.core.override_parser.overrides_parser import OverridesParser

    if not HydraConfig.initialized():
        return {"overrides": [], "choices": {}}
    hydra_cfg = HydraConfig.get()
    parser = OverridesParser.create()
    return {"overrides": [o for o in hydra_cfg.overrides.task if parser.parse_override(o).key_or_group != "resume"],
            "choices": {k: v for k, v in plain(hydra_cfg.runtime.choices).items()
                        if not (k == "hydra" or k.startswith(("hydra.", "hydra/")))}}


def without_secrets(cfg: DictConfig) -> dict:
    """The resolved config, but a served policy's shared secret (``policy.token``) as given — its
    ``${oc.env:GRT_POLICY_TOKEN,null}`` — never its value: what run folders and loggers may keep."""
    config = plain(cfg)
    if isinstance(config.get("policy"), dict) and config["policy"].get("token") is not None:
        config["policy"]["token"] = OmegaConf.to_container(cfg.policy, resolve=False)["token"]
    return config


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
    add_resolver("grt_motionplanning", motionplanning_dir)


register()
