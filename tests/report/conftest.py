"""A copy of the session's toy run (``toy_run``, tests/conftest.py) for a test to damage."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest


@pytest.fixture
def run_copy(toy_run, tmp_path) -> Path:
    """A copy of the toy run that a test may damage."""
    dst = tmp_path / "run"
    shutil.copytree(toy_run, dst)
    return dst
