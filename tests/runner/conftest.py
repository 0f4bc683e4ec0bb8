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


def refused_by_evaluate(overrides: list[str], out_dir: Path, capsys) -> tuple[int, str]:
    """``python -m grt.evaluate OVERRIDES``'s app run in this process: the composed config validated and
    evaluated under the app's own handler, as its ``main`` does; returns ``(exit code, stderr)`` of its
    refusal. Bad input is refused before any simulation, so this costs no process start (the command
    itself, as a user runs it, is checked on one case per task)."""
    from grt.cli._common import exit_on_user_error
    from grt.cli.evaluate import evaluate
    from grt.config import validate

    cfg = compose_run(overrides, config_name="evaluate")
    with pytest.raises(SystemExit) as info, exit_on_user_error():
        validate(cfg)
        evaluate(cfg, out_dir)
    return info.value.code, capsys.readouterr().err


@pytest.fixture
def conf_dir() -> Path:
    return CONF
