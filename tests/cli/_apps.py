"""GRT's command-line apps run in the test's process (``grt-<app> ARGS`` through its ``cli()``), for refusals
and cheap commands: a process start costs seconds here, and a refusal is decided before any simulation.

:func:`app` restores what an app changes in its process (``sys.argv``, Hydra's global state, the root
logger's handlers, the SIGTERM handler, ``logging.raiseExceptions``, Hydra's config of the app) and returns its exit code, stdout and
stderr. :func:`user_project` writes a user's project: a package of their own classes (``mypkg``) and a config
folder (``conf/``) with their policy, selector and experiment, as docs/your-own-code.md lays it out.
"""

from __future__ import annotations

import importlib
import logging
import signal
import sys
import textwrap
from pathlib import Path

from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig

ROOT = Path(__file__).resolve().parents[2]


def app(name: str, *argv: str, capsys) -> tuple[int, str, str]:
    """``grt-<name> ARGV`` in this process; returns ``(exit code, stdout, stderr)``."""
    module = importlib.import_module(f"grt.cli.{name}")
    root = logging.getLogger()
    saved = (sys.argv, root.handlers[:], root.level, signal.getsignal(signal.SIGTERM), logging.raiseExceptions)
    sys.argv = [f"grt-{name}", *argv]
    GlobalHydra.instance().clear()
    capsys.readouterr()
    try:
        module.cli()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:
        for handler in root.handlers[:]:
            if handler not in saved[1]:
                root.removeHandler(handler)
                handler.close()
        sys.argv, root.level, logging.raiseExceptions = saved[0], saved[2], saved[4]
        signal.signal(signal.SIGTERM, saved[3])
        GlobalHydra.instance().clear()
        HydraConfig.instance().cfg = None  # the app's config, which resolvers (${hydra:...}) would read later
    out = capsys.readouterr()
    return code, out.out, out.err


def error_line(err: str) -> str:
    """The one ``error:`` line of a refusal (and no traceback)."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


USER_CLASSES = '''
"""A user's own classes: a selector, a grasp planner, and classes whose constructors fail."""

import numpy as np

from grt.selectors.base import HandleSet


class CornerSelector:
    """The k vertices farthest from the centroid are the handles, the k nearest the anchors."""

    def __init__(self, k: int = 3):
        self.k = int(k)

    def select(self, mesh, task):
        far = np.argsort(np.linalg.norm(mesh.vertices - mesh.vertices.mean(0), axis=1))
        return HandleSet(far[-self.k:], far[: 4 * self.k], {"selector": "corners"})


class TablePlanner:
    """A grasp planner that finds nothing (the toy evaluator never calls it)."""

    def __init__(self, width: float = 0.08):
        self.width = width

    def plan(self, obs, seed):
        return []


class BrokenPolicy(TablePlanner):
    def __init__(self, threshold: float = 0.5):
        raise ValueError("weights file missing: /nowhere/weights.pt\\nsecond line")


class BrokenSelector(CornerSelector):
    def __init__(self, k: int = 3):
        raise RuntimeError("no GPU for my selector")
'''

USER_CONFIGS = {
    "policy/planner.yaml": "_target_: mypkg.TablePlanner\nwidth: 0.07\n",
    "policy/broken.yaml": "_target_: mypkg.BrokenPolicy\nthreshold: 0.4\n",
    "selector/corners.yaml": "_target_: mypkg.CornerSelector\nk: 3\n",
    "selector/broken.yaml": "_target_: mypkg.BrokenSelector\n",
    "experiment/mine.yaml": """\
        # @package _global_
        # a user's experiment: their policy and selector, the toy scoring of tests/runner/_toy_run.py
        defaults:
          - override /policy: planner
          - override /selector: corners
          - override /budget: smoke
        object: can
        budget:
          trials: 2
        task:
          session:
            _target_: tests.runner._toy_run.ToyTaskSession
        evaluator:
          _target_: tests.runner._toy_run.ToyEvaluator
        """,
}


def user_project(folder: Path) -> Path:
    """Write a user's project into ``folder`` (``mypkg/``, ``conf/``) and return it."""
    (folder / "mypkg").mkdir(parents=True)
    (folder / "mypkg" / "__init__.py").write_text(USER_CLASSES)
    for name, text in USER_CONFIGS.items():
        (folder / "conf" / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / "conf" / name).write_text(textwrap.dedent(text))
    return folder
