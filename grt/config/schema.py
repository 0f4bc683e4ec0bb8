"""The config's schemas and resolvers, registered before Hydra composes, and the budget's checks.

The ``budget`` group is validated by a dataclass schema (:data:`BudgetSchema`, made from
:class:`grt.plan.Budget`'s fields), so a misspelled key (``budget.trails=3``) or a value of the wrong type
(``budget.trials=abc``) fails when the config is composed, with the key's name in the message. Ranges
(``budget.trials=0``) are refused by :func:`check_budget` (:func:`grt.config.validate`).
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
from grt.errors import UserError
from grt.plan import BUDGET_KEYS, Budget, object_folder, object_name


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


def plain(node) -> dict | list:
    """A config node as plain Python containers, interpolations resolved (what library code takes)."""
    return OmegaConf.to_container(node, resolve=True)


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
    """Register schemas and resolvers (idempotent); the apps register their own (``resume_or``: :mod:`grt.cli`)."""
    cs = ConfigStore.instance()
    cs.store(group="budget", name="schema", node=BudgetSchema)
    add_resolver("object_name", object_name)
    add_resolver("object_folder", object_folder)
    # the installed package's folder (shipped checkpoints live under it), wherever GRT runs from
    add_resolver("grt_dir", lambda: str(Path(__file__).resolve().parents[1]))
    add_resolver("grt_motionplanning", motionplanning_dir)


register()
