"""A policy's ``worker_path`` (grt/evaluators/worker_env.py): its workers import numpy 1.26 from the folder
``make motionplanning`` fills, while the main process keeps numpy 2; jobs and outcomes cross intact.

Needs that folder (``make test`` makes it); without it these tests are skipped and say so.
"""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from grt.errors import UserError
from grt.evaluators.pool import Job, WorkerPool
from grt.evaluators.worker_env import WorkerPathError, run_in_worker, worker_path

HERE = Path(__file__).parent
ROOT = HERE.parents[1]
MP_DIR = ROOT / ".motionplanning"
needs_setup = pytest.mark.skipif(not (MP_DIR / "numpy").is_dir(),
                                 reason=f"no numpy 1.26 in {MP_DIR}: run `make motionplanning` (make test does)")
TASK = {"name": "probe", "session": {"_target_": "_numpy_probe.ProbeSession"}}


def _policy(path) -> dict:
    return {"_target_": "_numpy_probe.ProbePolicy", "worker_path": str(path)}


@needs_setup
def test_workers_run_the_policys_numpy_and_exchange_jobs_and_outcomes(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))  # the probe module, for the spawned workers too
    box = trimesh.creation.box((0.04, 0.05, 0.06))
    parts = [np.asarray(box.vertices, np.float64), np.asarray(box.vertices[:6], np.float32)]
    job = Job(0, 0, np.asarray(box.vertices), np.asarray(box.faces), parts, [2, 3])
    expect = float(np.sum(box.vertices)) + float(np.sum(box.faces)) + sum(float(np.sum(p)) for p in parts)
    pool = WorkerPool(TASK, _policy(MP_DIR), workers=1)
    outcomes = []
    try:
        pool.run([job], lambda _job, outcome, _s: outcomes.append(outcome))
    finally:
        pool.close()
    outcomes.sort(key=lambda o: o.seed)
    assert [o.info["numpy"] for o in outcomes] == ["1.26.4", "1.26.4"]
    assert np.__version__.startswith("2.")  # ... and this process kept its own
    assert [float(o.info["total"]) for o in outcomes] == pytest.approx([expect, expect], rel=1e-12)
    assert [o.score for o in outcomes] == [0.2, pytest.approx(0.3)]
    np.testing.assert_array_equal(outcomes[1].info["array"], [0.0, 3.0, 6.0])
    assert outcomes[0].info["ints"].dtype == np.int32


@needs_setup
def test_numpy_126_reads_numpy2_protocol5_pickles_once_mapped(tmp_path):
    """Ray (and multiprocessing from Python 3.14) pickle at protocol 5, which numpy 1.26 cannot read alone."""
    blob = tmp_path / "arrays.pkl"
    blob.write_bytes(pickle.dumps({"v": np.arange(6.0).reshape(2, 3)}, protocol=5))
    read = ("import pickle, sys; from grt.evaluators.worker_env import accept_numpy2_pickles\n"
            "if sys.argv[2] == 'map': accept_numpy2_pickles()\n"
            "import numpy; v = pickle.loads(open(sys.argv[1], 'rb').read())['v']; print(numpy.__version__, v.sum())")
    env = {"PYTHONPATH": f"{MP_DIR}:{ROOT}", "PATH": "/usr/bin:/bin"}
    plain = subprocess.run([sys.executable, "-c", read, str(blob), "plain"], capture_output=True, text=True, env=env)
    mapped = subprocess.run([sys.executable, "-c", read, str(blob), "map"], capture_output=True, text=True, env=env)
    assert plain.returncode != 0 and "numpy._core.numeric" in plain.stderr
    assert mapped.returncode == 0 and mapped.stdout.split() == ["1.26.4", "15.0"], mapped.stderr


def test_a_worker_path_that_does_not_exist_or_cannot_apply_is_refused(tmp_path):
    with pytest.raises(WorkerPathError, match=r"does not exist.*grt.setup motionplanning"):
        worker_path(_policy(tmp_path / "missing"))
    with pytest.raises(WorkerPathError, match="start_method=spawn"):
        WorkerPool(TASK, _policy(tmp_path), workers=1, start_method="forkserver")
    assert worker_path({"_target_": "x"}) == [] and worker_path(_policy(tmp_path)) == [str(tmp_path.resolve())]


@needs_setup
def test_a_command_runs_a_worker_path_policy_in_a_process_started_with_it(monkeypatch):
    """grt.calibrate runs its session through run_in_worker when the policy has a worker_path."""
    monkeypatch.syspath_prepend(str(HERE))
    import _numpy_probe

    assert run_in_worker([str(MP_DIR)], _numpy_probe.numpy_version, 0.5) == ("1.26.4", 6.5)
    with pytest.raises(UserError, match="^the set-up is missing$"):
        run_in_worker([str(MP_DIR)], _numpy_probe.refuse, "the set-up is missing")


@needs_setup
def test_the_planners_ik_restarts_follow_the_episode_seed_not_the_workers_past(monkeypatch):
    """mplib's IK restarts drew from one process-wide C ``rand()`` stream: a planner trial's outcome depended on
    the plans its worker had made before (a trial that failed in a run re-ran as a success in a fresh process)."""
    monkeypatch.syspath_prepend(str(HERE))
    import _numpy_probe

    fresh = run_in_worker([str(MP_DIR)], _numpy_probe.ik_restarts, str(MP_DIR), 7, 0)
    assert len(fresh.split()) == 9  # the Panda's 7 joints and 2 fingers
    assert run_in_worker([str(MP_DIR)], _numpy_probe.ik_restarts, str(MP_DIR), 7, 25) == fresh
    assert run_in_worker([str(MP_DIR)], _numpy_probe.ik_restarts, str(MP_DIR), 8, 0) != fresh
