"""GRT's imports only point down (scripts/check_layers.py): no cycle, no upward import, every module placed."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "scripts" / "check_layers.py"


@pytest.fixture(scope="module")
def checker():
    spec = importlib.util.spec_from_file_location("check_layers", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules["check_layers"] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("check_layers", None)


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    """A fake ``grt`` package in ``tmp_path`` with the given modules (path -> source)."""
    for name, source in {"grt/__init__.py": "", **files}.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(source)
    return tmp_path


def test_grt_imports_only_point_down():
    """The command anyone can run: zero violations in the package."""
    result = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.startswith("OK: ") and result.stdout.count("\n") == 1


def test_a_clean_package_is_ok(tmp_path, checker):
    root = _package(tmp_path, {
        "grt/errors.py": "",
        "grt/geometry/__init__.py": "",
        "grt/geometry/mesh.py": "from grt.errors import X\nfrom . import fidelity\n",
        "grt/geometry/fidelity.py": "import numpy\nfrom grt import errors\n",
    })
    problems, n_modules, n_edges = checker.check(root)
    assert problems == []
    assert (n_modules, n_edges) == (5, 3)


def test_an_upward_import_is_reported_with_its_line(tmp_path, checker):
    root = _package(tmp_path, {
        "grt/geometry/__init__.py": "",
        "grt/geometry/mesh.py": "import os\n\n\ndef f():\n    from grt.tasks.base import Task\n",
        "grt/tasks/__init__.py": "",
        "grt/tasks/base.py": "",
    })
    problems, _, _ = checker.check(root)
    assert problems == [f"{Path('grt/geometry/mesh.py')}:5: upward import: grt.geometry.mesh (L2) imports "
                        "grt.tasks.base (L6)"]


def test_a_cycle_is_reported_once_with_its_path(tmp_path, checker):
    root = _package(tmp_path, {
        "grt/geometry/__init__.py": "",
        "grt/geometry/mesh.py": "from .prepare import p\n",
        "grt/geometry/prepare.py": "from grt.geometry.quality import q\n",
        "grt/geometry/quality.py": "def q():\n    import grt.geometry.mesh\n",
    })
    problems, _, _ = checker.check(root)
    assert problems == ["import cycle: grt.geometry.mesh -> grt.geometry.prepare -> grt.geometry.quality "
                        "-> grt.geometry.mesh"]


def test_type_checking_imports_do_not_count(tmp_path, checker):
    root = _package(tmp_path, {
        "grt/geometry/__init__.py": "",
        "grt/geometry/mesh.py": ("from typing import TYPE_CHECKING\nimport typing\n"
                                 "if TYPE_CHECKING:\n    from grt.tasks.base import Task\n"
                                 "if typing.TYPE_CHECKING:\n    import grt.tasks.base\n"
                                 "else:\n    import grt.fileio\n"),
        "grt/fileio.py": "",
        "grt/tasks/__init__.py": "",
        "grt/tasks/base.py": "from grt.geometry.mesh import load\n",
    })
    problems, _, n_edges = checker.check(root)
    assert problems == []
    assert n_edges == 2  # mesh -> fileio (the else branch runs), tasks.base -> mesh


def test_unplaced_and_missing_modules_are_errors(tmp_path, checker):
    root = _package(tmp_path, {
        "grt/newthing.py": "from grt.nowhere import x\n",
    })
    problems, _, _ = checker.check(root)
    assert problems == [
        f"{Path('grt/newthing.py')}:1: module grt.newthing has no layer; place it in LAYERS in "
        "scripts/check_layers.py",
        f"{Path('grt/newthing.py')}:1: grt.newthing imports grt.nowhere, which is not a module of the package",
    ]


def test_python_m_shims_sit_on_top(checker):
    assert checker.layer_of("grt.blueteam.__main__") == checker.TOP
    assert checker.layer_of("grt.cli.run") == checker.TOP
    assert checker.layer_of("grt.geometry.mesh") == 2
    assert checker.layer_of("grt.unknown") is None


def test_the_command_fails_with_one_line_per_violation(tmp_path):
    root = _package(tmp_path, {
        "grt/errors.py": "from grt.config import ConfigError\n",
        "grt/config.py": "from grt.errors import UserError\n",
    })
    result = subprocess.run([sys.executable, str(SCRIPT), "--root", str(root)], capture_output=True, text=True)
    assert result.returncode == 1
    assert result.stdout.splitlines() == [
        f"{Path('grt/errors.py')}:1: upward import: grt.errors (L0) imports grt.config (L4)",
        "import cycle: grt.config -> grt.errors -> grt.config",
    ]


def test_hydra_and_omegaconf_only_in_the_app_layer_and_the_config_package(tmp_path, checker):
    """The library reads plain, typed settings: only ``grt.cli``, ``grt.bench``, the shims, ``grt.config`` (which
    turns the config into the plan) and ``grt.targets`` import Hydra or OmegaConf, function-local imports
    included."""
    root = _package(tmp_path, {
        "grt/config/__init__.py": "from omegaconf import OmegaConf\n",
        "grt/cli/__init__.py": "",
        "grt/cli/run.py": "import hydra\nfrom hydra.core.hydra_config import HydraConfig\n",
        "grt/run.py": "from omegaconf import DictConfig\n",
        "grt/geometry/__init__.py": "",
        "grt/geometry/mesh.py": "import os\n\n\ndef f():\n    from hydra.utils import instantiate\n",
        "grt/selectors/__init__.py": "import omegaconf.errors\n",
        "grt/blueteam/__init__.py": "",  # the apps' bodies too: they read the typed specs the apps make
        "grt/blueteam/study.py": "from omegaconf import DictConfig\n",
    })
    problems, _, _ = checker.check(root)
    why = ("Hydra and OmegaConf belong to the app layer (grt.cli, grt.bench, the python -m shims), grt.config, "
           "which turns the config into the run's plan, and grt.targets, which makes the objects a config names")
    assert problems == [f"{Path('grt/blueteam/study.py')}:1: grt.blueteam.study imports omegaconf: {why}",
                        f"{Path('grt/geometry/mesh.py')}:5: grt.geometry.mesh imports hydra.utils: {why}",
                        f"{Path('grt/selectors/__init__.py')}:1: grt.selectors imports omegaconf.errors: {why}"]


def test_the_layer_map_of_the_docs_is_the_one_measured(tmp_path, checker):
    root = _package(tmp_path, {"grt/errors.py": "", "grt/objects/__init__.py": ""})
    layers = {"grt": 0, "grt.errors": 0, "grt.objects": 1}
    page = tmp_path / "docs" / "architecture.md"
    page.parent.mkdir()
    table = "# A\n\n## Map: package\n\n| layer | package |\n|---|---|\n| L0 | `grt.errors` |\n| L1 | `grt.objects` |\n"
    page.write_text(table + "\n## Next\n| L7 | `grt.elsewhere` |\n")  # only the Map section's table counts
    assert checker.check(root, layers=layers)[0] == []
    page.write_text(table.replace("| L1 | `grt.objects` |", "| L2 | `grt.objects`, `grt.gone` |"))
    assert checker.check(root, layers=layers)[0] == [
        f"{Path('docs/architecture.md')}: the layer map puts grt.gone in L2, scripts/check_layers.py in no layer",
        f"{Path('docs/architecture.md')}: the layer map puts grt.objects in L2, scripts/check_layers.py in L1"]
