"""``pip install .`` (not editable) gives a GRT that runs from any folder: the wheel ships ``conf/`` as
``grt/conf`` (``setup.py``), where :data:`grt.CONF_DIR` finds it.

The wheel is built from a copy of the package's files (the build writes ``build/`` into its source tree),
installed with ``pip install --no-deps --target`` (its dependencies are this environment's), and its
commands run from a folder outside the repository with only the installed copy on ``PYTHONPATH``.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE_FILES = ("pyproject.toml", "setup.py", "README.md", "grt", "conf")


def _pip(*args: str, cwd: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "pip", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]


def _isolation() -> list[str]:
    """Build with this environment's setuptools when it is recent enough (no download), else isolated."""
    try:
        import setuptools

        return ["--no-build-isolation"] if int(setuptools.__version__.split(".")[0]) >= 77 else []
    except ImportError:
        return []


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The folder ``pip install --target`` installed the wheel of this checkout into."""
    base = tmp_path_factory.mktemp("install")
    src = base / "src"
    for name in PACKAGE_FILES:
        path = ROOT / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            src.mkdir(exist_ok=True)
            shutil.copy2(path, src / name)
    _pip("wheel", "--no-deps", *_isolation(), "-w", str(base / "dist"), str(src), cwd=base)
    (wheel,) = (base / "dist").glob("grt-*.whl")
    _pip("install", "--no-deps", "--target", str(base / "site"), str(wheel), cwd=base)
    return base / "site"


def _in(site: Path, cwd: Path, *command: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(site), "WANDB_MODE": "disabled"}
    env.pop("HYDRA_FULL_ERROR", None)
    return subprocess.run(list(command), cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_an_installed_wheel_runs_from_any_folder(installed, tmp_path):
    away = tmp_path / "elsewhere"
    away.mkdir()
    # the console script pip wrote, with the installed configs and --help's groups
    script = installed / "bin" / "grt-run"
    helped = _in(installed, away, str(script), "--help")
    assert helped.returncode == 0, helped.stderr[-3000:]
    assert helped.stdout.startswith("grt-run (python -m grt.run): red-team a policy")
    assert "policy: antipodal, contact_graspnet" in helped.stdout and "task: drawer, grasp" in helped.stdout
    # a real command from that folder: the select app composes conf/select.yaml and writes its folder here
    out = away / "outputs" / "sel"
    chosen = _in(installed, away, sys.executable, "-m", "grt.select", "object=can", f"hydra.run.dir={out}")
    assert chosen.returncode == 0, chosen.stdout[-3000:] + chosen.stderr[-3000:]
    assert json.loads((out / "handles.json").read_text())["handles"]
    sources = (out / ".hydra" / "hydra.yaml").read_text()  # the config folders it composed from
    assert f"path: {installed / 'grt' / 'conf'}" in sources and str(ROOT) not in sources
