"""Shared test fixtures. Tests compose the real configs with tiny budgets into tmp_path."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("WANDB_MODE", "disabled")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(0)
