"""Every documented command answers ``--help``, starting with one line that says what it does, and every console
script names an app with ``cli()``."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from grt.cli._common import about_line

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11

ROOT = Path(__file__).resolve().parents[2]
COMMANDS = ("run", "evaluate", "select", "deform", "bench", "objects", "report", "blueteam", "train", "serve",
            "replay", "calibrate", "setup", "profile")


def _cases(make) -> list:
    return [pytest.param(*make(name), id=name) for name in COMMANDS]


def _scripts() -> dict[str, str]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]


@pytest.mark.parametrize("name", _cases(lambda name: (name,)))
def test_python_m_help(name):
    proc = subprocess.run([sys.executable, "-m", f"grt.{name}", "--help"], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert proc.stdout.strip(), proc.stderr[-2000:]
    assert "Traceback" not in proc.stdout + proc.stderr
    assert proc.stdout.splitlines()[0] == about_line(name)  # what the command does, first
    if name == "serve":  # the groups it composes, not Hydra's stock page of every group
        groups = [line.split(":")[0] for line in proc.stdout.split("== Configuration groups ==")[1].split("== Config")[0]
                  .splitlines() if ": " in line and "(now: " in line]
        assert groups == ["policy", "task"], proc.stdout


def test_every_command_has_a_console_script():
    assert sorted(_scripts()) == sorted(f"grt-{name}" for name in COMMANDS)


@pytest.mark.parametrize(("script", "target"), _cases(lambda name: (f"grt-{name}", _scripts()[f"grt-{name}"])))
def test_console_script_names_an_app_with_cli(script, target):
    module, _, attr = target.partition(":")
    assert module == f"grt.cli.{script.removeprefix('grt-')}" and attr == "cli", target
    assert callable(getattr(importlib.import_module(module), attr))
