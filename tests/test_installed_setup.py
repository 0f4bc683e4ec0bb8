"""An installed GRT (no checkout) finds and makes what optional policies need in the user's own folders:
``python -m grt.setup motionplanning`` writes numpy 1.26 to ``~/.local/share/grt/motionplanning``, where
``policy=motion_planner`` looks by default, and every set-up message names that command, not a checkout's."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

import grt

ROOT = Path(__file__).resolve().parents[1]


def test_the_motion_planners_folder_is_the_checkouts_or_the_users(monkeypatch, tmp_path):
    monkeypatch.delenv("GRT_MOTIONPLANNING_DIR", raising=False)
    assert grt.CHECKOUT and grt.motionplanning_dir() == str(ROOT / ".motionplanning")
    monkeypatch.setattr(grt, "CHECKOUT", False)  # as a wheel in site-packages
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert grt.motionplanning_dir() == str(tmp_path / "data" / "grt" / "motionplanning")
    monkeypatch.delenv("XDG_DATA_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert grt.motionplanning_dir() == str(tmp_path / "home" / ".local" / "share" / "grt" / "motionplanning")
    monkeypatch.setenv("GRT_MOTIONPLANNING_DIR", str(tmp_path / "mine"))
    assert grt.motionplanning_dir() == str(tmp_path / "mine")


def test_an_installed_grt_is_sent_to_its_own_set_up_command_not_a_checkouts(tmp_path):
    """The planner's missing set-up named `make motionplanning` and a folder inside site-packages."""
    from grt.policies.cgn_net import INSTALL_HINT
    from grt.policies.motion_planner import MotionPlanningSetupError, check_setup

    with pytest.raises(MotionPlanningSetupError, match=r"run `python -m grt\.setup motionplanning` once"):
        check_setup(str(tmp_path / "missing"))
    assert INSTALL_HINT.startswith("python -m grt.setup cgn")
    with open(ROOT / "conf" / "paths" / "default.yaml") as f:
        assert "motionplanning: ${grt_motionplanning:}" in f.read()


def test_setup_motionplanning_into_a_folder_that_holds_it_says_so_without_installing(tmp_path):
    """Idempotent: a folder with the stamp and numpy 1.26 (the checkout's, made by ``make motionplanning``) is
    checked, not installed again."""
    mp = ROOT / ".motionplanning"
    if not (mp / ".grt-stamp").is_file():
        pytest.skip(f"no numpy 1.26 in {mp}: run `make motionplanning` (make test does)")
    proc = subprocess.run([sys.executable, "-m", "grt.setup", "motionplanning", "--dir", str(mp)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith(f"numpy==1.26.4 was already in {mp.resolve()}, mplib beside it"), proc.stdout
    importlib.invalidate_caches()


def test_building_the_wheel_leaves_nothing_git_would_show():
    """``pip install .`` from a checkout leaves ``build/`` (setuptools' work folder), which git listed."""
    proc = subprocess.run(["git", "check-ignore", "-q", "build/lib/grt/__init__.py"], cwd=ROOT)
    if proc.returncode == 128:
        pytest.skip("not a git checkout")
    assert proc.returncode == 0
