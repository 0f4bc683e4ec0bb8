"""``evaluator=ray`` on a real two-node Ray cluster (``ray start`` head + node, the ``ray_cluster`` fixture): trials
spread over both nodes equal the pool's, a node's workers killed mid-run change nothing in the journal, and a
cluster that cannot serve (no GRT module there, another Ray version, no token) is a one-line error.

Every driver is a process of its own, as a user's is (``grt.run``, ``grt.evaluate``, or a short script through
the public API); the cluster leaves no process behind (the fixture asserts it).
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray")

HERE = Path(__file__).parent
ROOT = HERE.parents[1]
SEEDS = [11, 12, 13, 14, 15, 16]

DRIVER = """
import json, logging, sys
import numpy as np, trimesh
from grt.evaluators.ray_pool import ClusterError, RayEvaluator
logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
task, policy, kwargs, seeds = (json.loads(a) for a in sys.argv[1:5])
data = np.load(sys.argv[5])
meshes = [trimesh.Trimesh(data[f"v{i}"], data[f"f{i}"], process=False) for i in range(len(data.files) // 2)]
try:
    with RayEvaluator(task, policy, nominal=meshes[0], progress=False, **kwargs) as ev:
        ev.start(say=None)
        results = ev.evaluate(meshes, seeds)
        print(json.dumps({"modes": [[[t.seed, t.mode, t.score] for t in r.trials] for r in results],
                          "info": ev.backend_info()}))
except ClusterError as exc:
    print(json.dumps({"error": str(exc)}))
"""


def _modes(results):
    return [[[t.seed, t.mode, t.score] for t in r.trials] for r in results]


def _drive(cluster, task, policy, meshes_file, env=None, **kwargs) -> tuple[dict, str]:
    """Run :data:`DRIVER` (a RayEvaluator joining ``cluster``) in a process of its own: (its JSON, stderr)."""
    kwargs = {"address": cluster.address, "workers": 2, **kwargs}
    proc = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(task), json.dumps(policy), json.dumps(kwargs),
                           json.dumps(SEEDS), str(meshes_file)], cwd=ROOT, env=env or cluster.driver_env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return json.loads(proc.stdout.strip().splitlines()[-1]), proc.stderr


@pytest.fixture(scope="module")
def toy(toy_reference, u_mesh, u_deformed, tmp_path_factory):
    """The pool's outcomes on [nominal, deformed] (the reference), the meshes in a file for the drivers."""
    assert toy_reference["seeds"] == SEEDS
    meshes = tmp_path_factory.mktemp("toy") / "meshes.npz"
    np.savez(meshes, v0=u_mesh.vertices, f0=u_mesh.faces, v1=u_deformed.vertices, f1=u_deformed.faces)
    return {"reference": _modes(toy_reference["results"]), "meshes": meshes, "cache_dir": toy_reference["cache_dir"]}


# --------------------------------------------------------------- toy session on the cluster
def test_trials_spread_over_both_nodes_equal_the_pools(ray_cluster, toy_configs, toy):
    """Three workers asked of a two-CPU cluster: a warning with both numbers, two actors, one per node."""
    task, policy = toy_configs()
    got, log = _drive(ray_cluster, task, policy, toy["meshes"], workers=3, cache_dir=toy["cache_dir"])
    assert got["modes"] == toy["reference"]
    assert f"evaluator.address={ray_cluster.address}: the cluster has 2 CPU, 3 workers x 1 = 3 asked; " \
           "starting 2 actors" in log
    info = got["info"]
    assert info["backend"] == "ray" and info["address"] == ray_cluster.address
    assert info["nodes"] == info["nodes_used"] == 2 and info["actors"] == 2 and info["actors_replaced"] == 0
    nodes = {key.split("/")[1] for key in info["trials_per_node"]}
    assert nodes == {ray_cluster.node_id(0)[:8], ray_cluster.node_id(1)[:8]}
    assert sum(info["trials_per_node"].values()) == 2 * len(SEEDS)


def test_a_task_module_the_nodes_cannot_import_is_a_cluster_error(ray_cluster, toy_configs, toy, tmp_path):
    """The task's module exists on the driver's machine only (its PYTHONPATH): the nodes say which is missing."""
    (tmp_path / "driver_only").mkdir()
    (tmp_path / "driver_only" / "grt_driver_only_task.py").write_text("from _toy_session import ToySession\n")
    task, policy = toy_configs()
    task["session"]["_target_"] = "grt_driver_only_task.ToySession"
    env = ray_cluster.driver_env(PYTHONPATH=str(tmp_path / "driver_only"))
    got, _ = _drive(ray_cluster, task, policy, toy["meshes"], env=env, cache_dir=toy["cache_dir"])
    python = ".".join(map(str, sys.version_info[:3]))
    assert got["error"].startswith(f"evaluator=ray: the node {socket.gethostname()} ({ray_cluster.node_ip(0)}) cannot "
                                   f"import 'grt_driver_only_task' (Python {python}); install GRT and the task's "
                                   "modules there"), got


VERSION = """
import json, sys
from ray._raylet import GcsClient
import ray._common.usage.usage_constants as usage_constant
import ray._private.ray_constants as ray_constants
from ray._common.usage import usage_lib
from grt.evaluators.ray_pool import ClusterError, RayPool
address = sys.argv[1]
gcs = GcsClient(address=address)
real = usage_lib.get_cluster_metadata(gcs)

def claim(metadata):
    gcs.internal_kv_put(usage_constant.CLUSTER_METADATA_KEY, json.dumps(metadata).encode(), overwrite=True,
                        namespace=ray_constants.KV_NAMESPACE_CLUSTER)

claim({**real, "ray_version": "2.9.3", "python_version": "3.10.12"})
try:
    RayPool({"session": {"_target_": "_toy_session.ToySession"}}, {"_target_": "_toy_session.ToyPolicy"},
            workers=1, address=address)
    print("joined")
except ClusterError as exc:
    print(exc)
finally:
    claim(real)
"""


def test_a_cluster_of_another_ray_version_is_a_one_line_error(ray_cluster):
    """The cluster's record of its versions (what ``ray.init`` checks) claims another Ray and Python for the
    length of the call: the driver's real version check fails, in one line naming both versions. (A cluster
    really running another Ray cannot be made here: one Ray install.)"""
    proc = subprocess.run([sys.executable, "-c", VERSION, ray_cluster.address], cwd=ROOT,
                          env=ray_cluster.driver_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-4000:]
    import ray

    mine = f"Ray {ray.__version__} on Python {'.'.join(map(str, sys.version_info[:3]))}"
    assert proc.stdout.strip().splitlines()[-1] == (
        f"evaluator.address={ray_cluster.address}: the cluster runs Ray 2.9.3 on Python 3.10.12, this machine "
        f"{mine}; install the same versions on both (pip install 'ray[default]==2.9.3')")


def test_a_driver_without_the_clusters_token_is_a_one_line_error(ray_cluster, toy_configs, toy):
    if ray_cluster.auth != "token":
        pytest.skip("the cluster runs without token authentication (no ~/.ray/auth_token here)")
    env = ray_cluster.driver_env(RAY_gcs_server_port_wait_time_s="1")  # Ray's connect window: 1 s, not 20
    env.pop("RAY_AUTH_MODE")  # a user's shell: Ray sends no token to a given address
    task, policy = toy_configs()
    got, _ = _drive(ray_cluster, task, policy, toy["meshes"], env=env, cache_dir=toy["cache_dir"])
    assert got["error"].startswith(f"evaluator.address={ray_cluster.address}: the cluster refused this machine's "
                                   "connection: it has token authentication on"), got
    assert "set RAY_AUTH_MODE=token here" in got["error"]


# --------------------------------------------------------------- the real simulator
RUN = ["task=insertion", "policy=insertion_state", "budget=smoke"]


def _journal(run_dir: Path) -> list[dict]:
    records = [json.loads(line) for line in (run_dir / "journal.jsonl").read_text().splitlines() if line.strip()]
    for r in records:  # wall_s is a time; the record's hash covers it
        r.pop("wall_s"), r.pop("sha256")
    return records


@pytest.mark.slow
def test_a_run_survives_losing_node2s_workers_and_equals_the_pools(ray_cluster, tmp_path):
    """A red-team run over both nodes; once its first candidate is in the journal, every worker process of the
    second node is killed (SIGKILL). The run finishes; its journal equals the worker pool's run (one worker, not
    interrupted), field for field but wall_s and the hash over it: no candidate lost, repeated or changed."""
    ray_dir, pool_dir = tmp_path / "ray", tmp_path / "pool"
    with (tmp_path / "pool.log").open("w") as log:  # beside the Ray run: it uses the machine's idle moments
        pool = subprocess.Popen([sys.executable, "-m", "grt.run", *RUN, "budget.workers=1", "evaluator=sim",
                                 f"hydra.run.dir={pool_dir}"], cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
    with (tmp_path / "ray.log").open("w") as log:
        run = subprocess.Popen([sys.executable, "-m", "grt.run", *RUN, "budget.workers=2", "evaluator=ray",
                                f"evaluator.address={ray_cluster.address}", f"hydra.run.dir={ray_dir}"],
                               cwd=ROOT, env=ray_cluster.driver_env(), stdout=log, stderr=subprocess.STDOUT)
    journal, killed = ray_dir / "journal.jsonl", []
    while run.poll() is None and not killed:
        if journal.exists() and journal.read_text().count("\n") >= 1:
            workers = ray_cluster.workers(1)
            killed = [" ".join(p.cmdline()).strip() for p in workers]
            for p in workers:
                p.kill()
        time.sleep(0.05)
    run.wait(timeout=600)
    out = (tmp_path / "ray.log").read_text()
    assert run.returncode == 0, out[-4000:]
    assert any(title.startswith("ray::SimActor") for title in killed), f"no actor among the killed: {killed}"

    assert pool.wait(timeout=600) == 0, (tmp_path / "pool.log").read_text()[-4000:]

    records = _journal(ray_dir)
    assert [(r["iteration"], r["candidate"]) for r in records] == \
           [(0, 0)] + [(t, c) for t in (1, 2) for c in range(3)]
    assert records == _journal(pool_dir)
    block = json.loads((ray_dir / "summary.json").read_text())["evaluator"]
    assert block["backend"] == "ray" and block["address"] == ray_cluster.address and block["nodes"] == 2
    assert block["actors_replaced"] >= 1, out[-3000:]  # the kill landed mid-run
    nodes = {key.split("/")[1]: n for key, n in block["trials_per_node"].items()}
    assert set(nodes) == {ray_cluster.node_id(0)[:8], ray_cluster.node_id(1)[:8]} and all(nodes.values())
    pool_block = json.loads((pool_dir / "summary.json").read_text())["evaluator"]
    assert sum(nodes.values()) == sum(pool_block["trials_per_node"].values())  # (invalid candidates run none)
