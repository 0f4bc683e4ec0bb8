"""``evaluator=ray`` on this machine with the toy session (issue 28): the same results as the worker pool,
crashes, hangs and exceptions handled as the pool handles them, and one-line errors for bad addresses.

The tests share one local Ray (the ``local_ray`` fixture, started through :func:`grt.evaluators.ray_pool.connect`
as ``address=local`` starts it); each :class:`RayEvaluator` joins it (``owned`` false) instead of starting and
stopping its own. Tests of the real simulator and of a real two-node cluster: ``test_ray_cluster.py``.
"""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf, open_dict

from grt.evaluators.ray_pool import ClusterError, RayEvaluator, connect, version_mismatch
from grt.evaluators.sim import SimEvaluator
from grt.targets import ClassError
from tests.conftest import GRASP_EVALUATION

ray = pytest.importorskip("ray")

HERE = Path(__file__).parent
ROOT = HERE.parents[1]
SEEDS = [11, 12, 13, 14, 15, 16]
#: two actors on this machine's Ray: two cores (a local Ray gets no more CPUs than the machine has cores)
two_cores = pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two CPU cores")


def _modes(results):
    return [[(t.seed, t.mode, t.score) for t in r.trials] for r in results]


def _child_env() -> dict:
    """The environment of a CLI child: no ``RAY_ADDRESS`` (it would override ``auto``)."""
    return {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}


def _rays_on_this_machine() -> set[str]:
    """GCS addresses ``address=auto`` would find here: the last ``ray start`` cluster, or any running raylet."""
    from ray._private import services, utils

    found = set(services.find_gcs_addresses())
    if (last := utils.read_ray_address(None)) is not None:
        found.add(last)
    return found


@pytest.fixture(scope="module")
def cache_dir(toy_reference):
    return toy_reference["cache_dir"]


@pytest.fixture(scope="module")
def reference(toy_reference):
    """The worker pool's outcomes on [nominal, deformed]: what Ray must reproduce."""
    assert toy_reference["seeds"] == SEEDS
    return toy_reference["results"]


@pytest.fixture(scope="module")
def local_ray():
    """One Ray on this machine (2 CPUs) for the module's evaluators; stopped at the end."""
    assert not ray.is_initialized()
    mode = os.environ.get("RAY_AUTH_MODE")
    assert connect("local", cpus=2, gpus=0, object_store_mb=256) is True
    yield ray
    ray.shutdown()
    if mode is None:  # ray.init turned token authentication on for this process and its children: not the rest's
        os.environ.pop("RAY_AUTH_MODE", None)
    else:
        os.environ["RAY_AUTH_MODE"] = mode


def _ray_evaluate(task, policy, meshes, cache_dir, **kwargs):
    with RayEvaluator(task, policy, workers=2, address="local", nominal=meshes[0], progress=False,
                      cache_dir=str(cache_dir), **kwargs) as ev:
        assert ev.pool.owned is False  # joined the module's Ray: closing it leaves that Ray up
        ev.start(say=None)  # every actor ready before the first job (as the CLIs do): all take part
        results = ev.evaluate(meshes, SEEDS)
        return results, ev.backend_info()


# --------------------------------------------------------------- bad addresses (no Ray of ours is up yet)
def _evaluate_cli(address: str, tmp_path: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "grt.evaluate", "object=can", "mesh.remesh=off", "budget=smoke",
                             "evaluator=ray", f"evaluator.address={address}", f"hydra.run.dir={tmp_path}"],
                            cwd=ROOT, env=_child_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _one_line_error(proc: subprocess.Popen, address: str, tmp_path: Path, why: str) -> None:
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err[-3000:]
    errors = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "Traceback" not in err, err[-3000:]
    assert f"evaluator.address={address}: {why}" in errors[0]
    assert "ray start --head" in errors[0] and "evaluator.address=local" in errors[0]  # how to get a cluster
    assert "simulator worker" not in out and not (tmp_path / "evaluation.json").exists()  # nothing simulated


def test_an_address_nobody_answers_is_a_one_line_error(tmp_path):
    _one_line_error(_evaluate_cli("127.0.0.1:1", tmp_path), "127.0.0.1:1", tmp_path,
                    "no Ray cluster answers there (Connection refused)")
    with pytest.raises(ClusterError, match=r"^evaluator.address=ray://127.0.0.1:1: no Ray cluster answers there "
                                           r"\(Connection refused\); start one with `ray start --head"):
        connect("ray://127.0.0.1:1", cpus=1, gpus=0, object_store_mb=None)  # Ray Client's address: the same


def test_auto_without_a_cluster_is_a_one_line_error(tmp_path):
    if ray.is_initialized() or (found := _rays_on_this_machine()):
        pytest.skip(f"a Ray runs on this machine ({ray.is_initialized() or found}): address=auto would join it")
    _one_line_error(_evaluate_cli("auto", tmp_path), "auto", tmp_path, "no running Ray cluster found")


@pytest.mark.parametrize("address", ["nowhere", "10.0.0.1:port"])
def test_an_address_that_is_no_address_says_what_to_give(address):
    with pytest.raises(ClusterError, match=rf"evaluator.address={address}: not an address; give local, auto"):
        connect(address, cpus=1, gpus=0, object_store_mb=None)


def test_version_mismatch_is_one_line_with_both_versions():
    """Ray's own messages (``check_version_info``, as ``ray.init`` and Ray Client raise them) -> one line."""
    from ray._private.utils import check_version_info

    messages = []
    for where, level in (("node 10.0.0.2", "patch"), ("Ray Client", "minor")):  # ray.init / ray:// address
        with pytest.raises(RuntimeError) as caught:
            check_version_info({"ray_version": "2.9.3", "python_version": "3.10.12"}, where,
                               python_version_match_level=level)
        messages.append(str(caught.value))
    mine = f"Ray {ray.__version__} on Python {'.'.join(map(str, sys.version_info[:3]))}"
    for message, address in zip(messages, ["10.0.0.1:6379", "ray://10.0.0.1:10001"], strict=True):
        assert message.startswith("Version mismatch: The cluster was started with:")
        line = version_mismatch(message, address)
        assert line == (f"evaluator.address={address}: the cluster runs Ray 2.9.3 on Python 3.10.12, this machine "
                        f"{mine}; install the same versions on both (pip install 'ray[default]==2.9.3')")
    assert version_mismatch("Could not find any running Ray instance.", "auto") is None


# --------------------------------------------------------------- toy session on the module's local Ray
@two_cores
def test_same_results_as_the_pool(toy_configs, u_mesh, u_deformed, reference, cache_dir, local_ray):
    task, policy = toy_configs()
    results, info = _ray_evaluate(task, policy, [u_mesh, u_deformed], cache_dir)
    assert _modes(results) == _modes(reference)  # every trial's seed, outcome and score
    assert [r.score for r in results] == [r.score for r in reference]
    assert [r.outcomes for r in results] == [r.outcomes for r in reference]
    assert len({t.info["pid"] for r in results for t in r.trials}) == 2  # both actors ran trials
    assert info["backend"] == "ray" and info["address"] == "local" and info["nodes"] == info["nodes_used"] == 1
    assert info["actors"] == 2 and info["actors_replaced"] == 0
    assert sum(info["trials_per_node"].values()) == 2 * len(SEEDS)
    assert ray.is_initialized()  # the evaluator did not stop the Ray it did not start


def test_a_transient_crash_and_a_transient_hang_are_rerun(toy_configs, u_mesh, reference, cache_dir, tmp_path,
                                                          local_ray):
    """An actor that dies (or hangs past trial_timeout, and is killed) is replaced; its seeds run again."""
    task, policy = toy_configs(crash_on=12, crash_once_marker=str(tmp_path / "crashed"),
                               hang_on=15, hang_once_marker=str(tmp_path / "hung"))
    (result,), info = _ray_evaluate(task, policy, [u_mesh], cache_dir, trial_timeout=3.0)
    assert (tmp_path / "crashed").exists() and (tmp_path / "hung").exists()
    assert _modes([result]) == _modes(reference[:1])
    assert info["actors_replaced"] >= 2


def test_a_seed_that_always_kills_its_actor_and_a_trial_that_raises_are_sim_errors(toy_configs, u_mesh, reference,
                                                                                   cache_dir, local_ray):
    task, policy = toy_configs(crash_on=12, raise_on=14)
    (result,), info = _ray_evaluate(task, policy, [u_mesh], cache_dir, max_retries=1)
    died, raised = result.trials[SEEDS.index(12)], result.trials[SEEDS.index(14)]
    assert died.mode == "sim_error" and "Ray actor died on " in died.info["error"] and "2 times" in died.info["error"]
    assert raised.mode == "sim_error" and "physics exploded on seed 14" in raised.info["error"]
    # Three deaths where the pool has two: the first left seeds 12 and 13 unanswered (an actor that dies can take
    # the answer of its last finished trial with it), so it blamed no seed and the job went on one trial at a time.
    assert info["actors_replaced"] == 3
    for got, want in zip(result.trials, reference[0].trials, strict=True):
        if got.seed not in (12, 14):
            assert (got.mode, got.score) == (want.mode, want.score)


def test_a_session_that_cannot_be_built_is_a_clear_error(toy_configs, u_mesh, cache_dir, local_ray):
    task, policy = toy_configs(fail_build=True)
    with pytest.raises(ClassError, match="could not be built in an evaluator actor on .*: RuntimeError: toy session "
                       "refuses to build"):
        _ray_evaluate(task, policy, [u_mesh], cache_dir)


@two_cores
def test_more_workers_than_cpus_start_as_many_actors_as_fit(toy_configs, u_mesh, reference, cache_dir, local_ray,
                                                           caplog):
    """Two CPUs, two workers of two CPUs each: a warning with the numbers, and the run goes on with one actor."""
    task, policy = toy_configs()
    with caplog.at_level(logging.WARNING, logger="grt.evaluators.ray_pool"):
        (result,), info = _ray_evaluate(task, policy, [u_mesh], cache_dir, num_cpus=2)
    assert "the cluster has 2 CPU, 2 workers x 2 = 4 asked; starting 1 actor" in caplog.text
    assert info["actors"] == 1 and len({t.info["pid"] for t in result.trials}) == 1
    assert _modes([result]) == _modes(reference[:1])


@two_cores
def test_evaluation_json_says_where_the_trials_ran(toy_configs, u_mesh, tmp_path, local_ray):
    from grt.bench.grasp import compose
    from grt.cli.evaluate import evaluate

    path = tmp_path / "u_block.ply"
    u_mesh.export(path)
    cfg = compose([f"object={path}", "budget=smoke", "budget.trials=4", "budget.workers=2", "evaluator=ray",
                   "evaluator.progress=false", f"evaluator.cache_dir={tmp_path / 'coacd'}"])
    task, policy = toy_configs()
    with open_dict(cfg):
        cfg.task.session = OmegaConf.create(task["session"])
    cfg.policy = OmegaConf.create(policy)
    evaluate(cfg, tmp_path / "out")
    block = json.loads((tmp_path / "out" / "evaluation.json").read_text())["evaluator"]
    assert block["backend"] == "ray" and block["address"] == "local" and block["ray"] == ray.__version__
    assert block["nodes"] == block["nodes_used"] == 1 and block["actors"] == 2 and block["actors_replaced"] == 0
    (node, trials), = block["trials_per_node"].items()
    assert trials == 4 and node.split("/")[1] == ray.get_runtime_context().get_node_id()[:8]


# --------------------------------------------------------------- the pool, for comparison
def test_the_pool_kills_a_hung_worker_too(toy_configs, u_mesh, reference, cache_dir):
    task, policy = toy_configs(hang_on=13)
    with SimEvaluator(task, policy, workers=1, nominal=u_mesh, progress=False, cache_dir=str(cache_dir),
                      max_retries=0, trial_timeout=3.0) as ev:
        (result,) = ev.evaluate([u_mesh], SEEDS)
    hung = result.trials[SEEDS.index(13)]
    assert hung.mode == "sim_error" and "timed out (hung), 1 times" in hung.info["error"]
    for got, want in zip(result.trials, reference[0].trials, strict=True):
        if got.seed != 13:
            assert (got.mode, got.score) == (want.mode, want.score)


# --------------------------------------------------------------- the real simulator
@pytest.mark.slow
def test_grasp_trials_equal_the_pools_bit_for_bit(grasp_evaluation, tmp_path):
    """The grasp task's real simulation (GraspSession, antipodal policy; the two-camera variant: a process's first
    depth capture takes ~5 s there, ~12 s with six): ``grt.evaluate`` with evaluator=ray, on a Ray the command
    starts and stops (address=local), writes the trials evaluator=sim writes (the suite's shared evaluation,
    conftest.py's ``GRASP_EVALUATION``), field for field but the times."""
    proc = subprocess.run([sys.executable, "-m", "grt.evaluate", *GRASP_EVALUATION, "evaluator=ray",
                           f"hydra.run.dir={tmp_path / 'ray'}"],
                          cwd=ROOT, env=_child_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    on_ray = json.loads((tmp_path / "ray" / "evaluation.json").read_text())
    sim = json.loads((grasp_evaluation[0] / "evaluation.json").read_text())
    assert sim["evaluator"]["backend"] != "ray" and len(sim["trials"]) == 2 and on_ray["seeds"] == sim["seeds"]
    assert [_timeless(t) for t in on_ray["trials"]] == [_timeless(t) for t in sim["trials"]]
    assert (on_ray["score"], on_ray["outcomes"], on_ray["mesh_hash"]) == (sim["score"], sim["outcomes"], sim["mesh_hash"])
    block = on_ray["evaluator"]
    assert (block["backend"], block["address"], block["nodes"], block["actors_replaced"]) == ("ray", "local", 1, 0)
    assert sum(block["trials_per_node"].values()) == 2
    host, port = block["gcs_address"].rsplit(":", 1)
    with pytest.raises(OSError):  # the command stopped the Ray it started
        socket.create_connection((host, int(port)), timeout=2.0).close()


def _timeless(trial: dict) -> dict:
    """A trial record without its timings (``info``'s ``*_s``: capture, planning, simulation, wall)."""
    return {**trial, "info": {k: v for k, v in trial["info"].items() if not k.endswith("_s")}}


def test_racing_on_ray_stops_candidates_as_the_pool_does(toy_configs, u_mesh, u_deformed, reference, cache_dir,
                                                         local_ray):
    """A raced evaluation on Ray actors: the same trials as the pool's racing (the seeds' first rounds), and the
    rounds after a stop never run (issue 39)."""
    from tests.evaluators.test_racing import StopAt

    task, policy = toy_configs()
    with RayEvaluator(task, policy, workers=2, address="local", nominal=u_mesh, progress=False,
                      cache_dir=str(cache_dir)) as ev:
        ev.start(say=None)
        results = ev.evaluate([u_mesh, u_deformed], SEEDS, race=StopAt(when=4))
        info = ev.backend_info()
    assert _modes(results) == [trials[:4] for trials in _modes(reference)]
    assert sum(info["trials_per_node"].values()) == 2 * 4
    assert [r.info["race"]["trials"] for r in results] == [4, 4]
