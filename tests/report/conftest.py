"""One toy red-team run (the real loop, deformer and outputs; trials scored without the simulator by
``tests/runner/_toy_run.py``'s geometry-aware policy, so some fail) made once per test session."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def toy_run(tmp_path_factory) -> Path:
    from grt.runner import run
    from tests.runner._toy_run import TOY
    from tests.runner.conftest import compose_run

    out = tmp_path_factory.mktemp("toy_run")
    cfg = compose_run(["budget=smoke", "selector.k=3", "budget.sigma=0.06", "budget.trials=4", "budget.confirm_trials=4",
                       "+evaluator.bar_mm=4", *TOY, f"paths.output_dir={out}"])
    run(cfg)
    return out


@pytest.fixture
def run_copy(toy_run, tmp_path) -> Path:
    """A copy of the toy run that a test may damage."""
    dst = tmp_path / "run"
    shutil.copytree(toy_run, dst)
    return dst
