"""Compose the real configs (as lightning-hydra-template's tests do) with tiny budgets."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

import grt.config  # noqa: F401  (schemas and resolvers)

CONF = Path(__file__).resolve().parents[2] / "conf"


def compose_run(overrides: list[str], config_name: str = "run"):
    """The composed root config, as ``python -m grt.run <overrides>`` would see it."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name=config_name, overrides=overrides)


@pytest.fixture
def conf_dir() -> Path:
    return CONF
