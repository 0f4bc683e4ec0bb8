"""Typed config schemas and OmegaConf resolvers, registered before Hydra composes.

The ``budget`` group is validated by a dataclass schema, so a misspelled key (``budget.trails=3``)
fails when the config is composed, with the key's name in the message. Groups with a ``_target_``
are checked by the class signature at instantiation (an unknown key names itself in the TypeError).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf


@dataclass
class BudgetSchema:
    """The numbers of a search (paper appendix, lines 1062-1099).

    Attributes:
        population: candidates per iteration (paper: 10).
        iterations: ``T`` (paper: 10).
        trials: simulated episodes per candidate (paper: 64 for grasping).
        sigma: std of the Gaussian over handle displacements, unit-cube units (paper: 0.001).
        seed: seeds the optimizer and the episode seeds (paper: 42).
        workers: simulator worker processes.
        tau: Smoothness-Score budget in meters (``None``: off).
        top_k: CrashShapes saved in the run folder.
    """

    population: int = 10
    iterations: int = 10
    trials: int = 64
    sigma: float = 0.001
    seed: int = 42
    workers: int = 2
    tau: float | None = None
    top_k: int = 3


def object_name(spec: str) -> str:
    """A short name for an object spec: the built-in name, or a file's stem."""
    text = str(spec)
    return Path(text).stem if ("/" in text or "." in text) else text


def register() -> None:
    """Register schemas and resolvers (idempotent)."""
    cs = ConfigStore.instance()
    cs.store(group="budget", name="schema", node=BudgetSchema)
    if not OmegaConf.has_resolver("object_name"):
        OmegaConf.register_new_resolver("object_name", object_name)
    if not OmegaConf.has_resolver("grt_dir"):
        # the installed package's folder (shipped checkpoints live under it), wherever GRT runs from
        OmegaConf.register_new_resolver("grt_dir", lambda: str(Path(__file__).resolve().parent))
    if not OmegaConf.has_resolver("resume_or"):
        # hydra.run.dir: continue in the resumed run's own folder instead of creating a new one
        OmegaConf.register_new_resolver("resume_or", lambda resume, default: resume or default)


register()
