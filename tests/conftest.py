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


# A real grasp red-team run with the smallest budget that runs the whole loop: two small cameras keep CPU
# rendering cheap; with 2 trials S0 may be 0, so no nominal floor (test_nominal_floor.py covers the floor).
GRASP_SMOKE = ["budget=smoke", "budget.confirm_trials=2", "task.session.num_cameras=2",
               "task.session.camera_width=160", "task.session.camera_height=120", "selector.k=4",
               "task.nominal_floor=null"]


def _grt_piped(*args: str, timeout: float = 900):
    """``python -m ARGS`` from the repository root with stdout and stderr piped (as in a log or CI)."""
    import subprocess
    import sys
    from pathlib import Path

    return subprocess.run([sys.executable, "-m", *args], cwd=Path(__file__).resolve().parents[1],
                          capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="session")
def grasp_smoke_run(tmp_path_factory):
    """``(run folder, finished process)`` of one real ``python -m grt.run`` on the grasp task (``GRASP_SMOKE``),
    made once per session: a simulator start costs more than the whole smoke search, so the tests that read
    a real run's folder (artifacts, replay) or its piped output (the log) share this one."""
    return _once(tmp_path_factory, "grasp_smoke", lambda folder: _grt_piped(
        "grt.run", *GRASP_SMOKE, f"hydra.run.dir={folder / 'run'}"), "run")


def _once(tmp_path_factory, name: str, make, sub: str):
    """``(folder / sub, finished process)`` of ``make(folder)`` (a piped ``python -m grt...``), made once per
    test run: a session fixture is made once per pytest-xdist worker, so the workers share one folder of the
    run's temporary root, the first one makes it under a file lock and the others read its recorded process."""
    import json
    import subprocess

    from filelock import FileLock

    if os.environ.get("PYTEST_XDIST_WORKER") is None:  # one process: nobody to share with
        folder = tmp_path_factory.mktemp(name)
        proc = make(folder)
    else:
        root = tmp_path_factory.getbasetemp().parent  # the run's root, above each worker's own
        folder, record = root / name, root / f"{name}.json"
        with FileLock(str(root / f"{name}.lock")):
            if record.exists():
                proc = subprocess.CompletedProcess(**json.loads(record.read_text()))
            else:
                folder.mkdir(exist_ok=True)
                proc = make(folder)
                if proc.returncode == 0:
                    record.write_text(json.dumps({"args": proc.args, "returncode": proc.returncode,
                                                  "stdout": proc.stdout, "stderr": proc.stderr}))
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return folder / sub, proc


# A real evaluation of the can by the antipodal planner: two small cameras, 2 trials, 1 worker.
GRASP_EVALUATION = ["task=grasp_2cam", "object=can", "policy=antipodal", "budget.trials=2", "budget.workers=1"]


@pytest.fixture(scope="session")
def grasp_evaluation(tmp_path_factory):
    """``(output folder, finished process)`` of one real ``python -m grt.evaluate GRASP_EVALUATION`` (progress
    on), piped; shared by the tests of its log, of its JSON line and of the same policy served
    (test_serve.py compares the served planner's trials with these)."""
    return _once(tmp_path_factory, "grasp_evaluation", lambda folder: _grt_piped(
        "grt.evaluate", *GRASP_EVALUATION, f"hydra.run.dir={folder / 'out'}"), "out")
