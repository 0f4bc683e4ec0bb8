"""Shared test fixtures. Tests compose the real configs with tiny budgets into tmp_path."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("WANDB_MODE", "disabled")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def toy_run(tmp_path_factory):
    """One finished red-team run folder, made once per test session: the real loop, deformer, outputs and
    report, trials scored without the simulator by ``tests/runner/_toy_run.py``'s policy that fails on
    moved shapes (so the CrashShapes have failing trials)."""
    from grt.runner import run
    from tests.runner._toy_run import TOY
    from tests.runner.conftest import compose_run

    out = tmp_path_factory.mktemp("toy_run")
    cfg = compose_run(["budget=smoke", "selector.k=3", "budget.sigma=0.06", "budget.trials=4",
                       "budget.confirm_trials=4", "+evaluator.bar_mm=4", *TOY, f"paths.output_dir={out}"])
    run(cfg)
    return out
