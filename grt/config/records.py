"""Config files and command lines as plain data, for the library: the one place that reads Hydra's grammar.

A run folder keeps its config in YAML (``run_config.yaml``, Hydra's ``.hydra/config.yaml``) and its command
line as Hydra overrides. :mod:`grt.runfolder` reads and writes them through these functions, as plain
Python data: :func:`read_yaml` / :func:`yaml_text` (OmegaConf's YAML, interpolations kept as written),
:func:`parse_overrides` (Hydra's override grammar, as :class:`Override` values), :class:`ConfigView`
(dotted keys of a config, its interpolations resolved as OmegaConf resolves them), :func:`chosen`
(the option of a config group the running app chose, to word a message).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf


def read_yaml(path: str | Path) -> Any:
    """A YAML file as plain data, interpolations (``${...}``) kept as written (OmegaConf's reading).

    Raises:
        OSError, ValueError: the file cannot be read or parsed (OmegaConf's and PyYAML's errors are
            ``ValueError`` subclasses or carry their own type; callers name the file).
    """
    return OmegaConf.to_container(OmegaConf.load(path), resolve=False)


def resolved(source: str | Path | Mapping) -> Any:
    """A YAML file, or a mapping, as plain data with its interpolations resolved (``defaults`` left out: a
    file read alone is not composed)."""
    node = OmegaConf.create(dict(source)) if isinstance(source, Mapping) else OmegaConf.load(source)
    if isinstance(node, DictConfig):
        node.pop("defaults", None)
    return OmegaConf.to_container(node, resolve=True)


def chosen(group: str) -> str | None:
    """The option of a config group the running Hydra app chose (``policy=NAME``), or ``None`` outside an app."""
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        found = HydraConfig.get().runtime.choices.get(group)
        return str(found) if found is not None else None
    return None


def yaml_text(data: Mapping) -> str:
    """``data`` as OmegaConf writes YAML (what Hydra's own records look like)."""
    return OmegaConf.to_yaml(data)


@dataclass(frozen=True)
class Override:
    """One command-line override, as Hydra reads it.

    Attributes:
        key: its key or config group (``budget.trials``, ``selector``, ``hydra/launcher``).
        value: its value as Hydra parses it (``3``, ``"all"``, a list); ``None`` for a sweep or a deletion.
        line: the override as given (``budget.trials=3``).
        sweep: a sweep (``a=1,2``, ``range(...)``); add: ``+key=...``; delete: ``~key``.
    """

    key: str
    value: Any
    line: str
    sweep: bool = False
    add: bool = False
    delete: bool = False


def parse_overrides(lines: list[str]) -> list[Override] | None:
    """``lines`` as Hydra reads them, or ``None`` when one is malformed (Hydra reports it itself)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    try:
        parsed = OverridesParser.create().parse_overrides(list(lines))
    except HydraException:
        return None
    return [Override(o.key_or_group, None if o.is_sweep_override() or o.is_delete() else o.value(), o.input_line,
                     o.is_sweep_override(), o.is_add(), o.is_delete()) for o in parsed]


def override_key(line: str) -> str:
    """The key (or config group) of one well-formed override."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return OverridesParser.create().parse_override(line).key_or_group


def reads_back(line: str, key: str, value: str) -> bool:
    """Whether Hydra reads the override ``line`` as ``key`` set to the string ``value``."""
    parsed = parse_overrides([line])
    return bool(parsed) and parsed[0].key == key and parsed[0].value == value


class ConfigView:
    """A plain config read as OmegaConf reads it: dotted keys, interpolations resolved against the config."""

    def __init__(self, config: Mapping):
        self._cfg = config if isinstance(config, DictConfig) else OmegaConf.create(dict(config))

    def get(self, key: str, default: Any = None, resolve: bool = True) -> Any:
        """The value at dotted ``key``, ``default`` where it is absent, ``None`` where it does not resolve
        (``${hydra:...}`` outside Hydra); a mapping or list comes back plain (resolved unless ``resolve`` is
        false)."""
        return _plain(OmegaConf.select(self._cfg, key, default=default, throw_on_resolution_failure=False), resolve)

    def resolve(self, key: str) -> Any:
        """The value at dotted ``key`` resolved (``None`` where it is absent); one that does not resolve raises
        OmegaConf's error."""
        return _plain(OmegaConf.select(self._cfg, key, throw_on_resolution_failure=True), True)


def _plain(value, resolve: bool):
    return OmegaConf.to_container(value, resolve=resolve) if isinstance(value, (DictConfig, ListConfig)) else value
