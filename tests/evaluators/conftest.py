"""Fixtures of the evaluation tests: a small concave solid, its deformation, toy task sessions."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import manifold3d as m3
import numpy as np
import pytest
import trimesh

from grt.geometry.deform import ShapeDeformer

HERE = Path(__file__).parent


def u_shape() -> trimesh.Trimesh:
    """A 6 x 3 x 5 cm U-shaped block (a slot cut from the top), resting on z = 0, ~1.2k faces."""
    outer = m3.Manifold.cube([0.06, 0.03, 0.05])
    slot = m3.Manifold.cube([0.03, 0.04, 0.04]).translate([0.015, -0.005, 0.012])
    solid = (outer - slot).translate([-0.03, -0.015, 0.0]).refine_to_length(0.006).to_mesh()
    return trimesh.Trimesh(np.asarray(solid.vert_properties)[:, :3], np.asarray(solid.tri_verts), process=False)


@pytest.fixture(scope="session")
def u_mesh() -> trimesh.Trimesh:
    return u_shape()


@pytest.fixture(scope="session")
def u_deformed(u_mesh) -> trimesh.Trimesh:
    """The U-shape with its two top corners pulled apart (~3 mm), same faces."""
    v = u_mesh.vertices
    anchors = np.flatnonzero(v[:, 2] < 1e-6)
    top = np.flatnonzero(v[:, 2] > 0.05 - 1e-6)
    handles = top[np.argsort(v[top, 0])[[0, -1]]]
    deformer = ShapeDeformer(u_mesh, handles, anchors)
    return deformer.meshes(np.array([[[-0.05, 0.0, 0.03], [0.05, 0.02, 0.0]]]))[0]


@pytest.fixture(scope="session")
def toy_configs():
    """``(task, policy)`` dicts building :class:`_toy_session.ToySession` in worker processes."""

    def make(**session_kwargs):
        task = {"name": "toy", "session": {"_target_": "_toy_session.ToySession", **session_kwargs}}
        policy = {"_target_": "_toy_session.ToyPolicy", "fill": 0.5}
        return task, policy

    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(HERE))  # spawned workers inherit sys.path
        yield make


TOY_SEEDS = [11, 12, 13, 14, 15, 16]


@pytest.fixture(scope="session")
def toy_reference(toy_configs, u_mesh, u_deformed, tmp_path_factory) -> dict:
    """The worker pool's results (one worker) of the healthy toy session on [nominal, deformed] over ``seeds``:
    what other evaluators must reproduce; ``cache_dir`` holds the nominal's CoACD parts."""
    from grt.evaluators.sim import SimEvaluator

    cache_dir = str(tmp_path_factory.mktemp("toy_coacd"))
    task, policy = toy_configs()
    with SimEvaluator(task, policy, workers=1, nominal=u_mesh, progress=False, cache_dir=cache_dir) as ev:
        results = ev.evaluate([u_mesh, u_deformed], TOY_SEEDS)
    return {"seeds": list(TOY_SEEDS), "results": results, "cache_dir": cache_dir}


# ------------------------------------------------------------------------------------ a real Ray cluster
class RayCluster:
    """A real two-node Ray cluster on this machine: ``ray start --head`` and one ``ray start --address``,
    1 CPU each, each a process group of its own, Ray's files in a private temp dir (``address=auto`` does
    not read it). Both nodes import GRT and the toy session (``PYTHONPATH``), as an installed cluster would.

    ``stop()`` ends both groups (SIGTERM, then SIGKILL) and returns what is still alive: every process the
    cluster ever had (descendants seen, group members, command lines naming its temp dir).

    Authentication: token (Ray's default where ``~/.ray/auth_token`` exists, as any ``ray.init`` here made
    it), else none. A driver joining a given address sends its token only with ``RAY_AUTH_MODE=token``, and
    a driver of the other mode breaks its actors: drivers run with :meth:`driver_env`.
    """

    def __init__(self, logs: Path):
        import tempfile

        self.temp_dir = Path(tempfile.mkdtemp(prefix="grt-ray-", dir="/tmp"))  # short: unix socket paths <= 107
        self.logs, self.port = logs, _free_port()
        self.address = f"127.0.0.1:{self.port}"
        self.procs: list = []
        self.seen: dict[int, object] = {}  # pid -> psutil.Process, every descendant ever seen
        self.auth = "token" if (Path.home() / ".ray" / "auth_token").exists() else "disabled"
        self.env = self.driver_env()
        self.env.update(PYTHONPATH=os.pathsep.join([str(HERE.parents[1]), str(HERE)]),
                        RAY_GRACEFUL_SHUTDOWN_DRAIN_TIMEOUT_S="0")  # SIGTERM stops a node at once

    def driver_env(self, **extra: str) -> dict:
        """The environment of a driver process joining this cluster (``RAY_AUTH_MODE`` as the cluster's)."""
        env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
        return {**env, "RAY_AUTH_MODE": self.auth, **extra}

    def start(self, timeout: float = 120.0) -> RayCluster:
        import sys
        import time

        ray = str(Path(sys.executable).parent / "ray")
        common = ["--num-cpus", "1", "--temp-dir", str(self.temp_dir), "--disable-usage-stats",
                  "--object-store-memory", str(100 * 1024 * 1024), "--dashboard-agent-listen-port",
                  str(_free_port()), "--block"]
        end = time.monotonic() + timeout
        self._launch("head", [ray, "start", "--head", "--port", str(self.port), "--include-dashboard=false",
                              "--dashboard-port", str(_free_port()), "--ray-client-server-port",
                              str(_free_port()), *common])
        while not _answers(self.port):  # the head's GCS is up: the node can join while the head finishes
            self._check(0, end)
        self._launch("node2", [ray, "start", "--address", self.address, *common])
        for node in (0, 1):
            while "Ray runtime started" not in (self.logs / f"node{node}.log").read_text():
                self._check(node, end)
            self.raylet(node)  # registered: its raylet runs
        return self

    def _launch(self, name: str, command: list[str]) -> None:
        import subprocess

        with (self.logs / f"node{len(self.procs)}.log").open("w") as out:
            self.procs.append(subprocess.Popen(command, env=self.env, stdout=out, stderr=subprocess.STDOUT,
                                               stdin=subprocess.DEVNULL, start_new_session=True))

    def _check(self, node: int, end: float) -> None:
        import time

        if self.procs[node].poll() is not None or time.monotonic() > end:
            raise RuntimeError(f"ray start (node {node}) failed:\n{(self.logs / f'node{node}.log').read_text()[-4000:]}")
        time.sleep(0.1)

    # ---------------------------------------------------------------- processes
    def _scan(self) -> list:
        import psutil

        found = []
        for proc in self.procs:
            with contextlib.suppress(psutil.NoSuchProcess):
                top = psutil.Process(proc.pid)
                found += [top, *top.children(recursive=True)]
        for p in found:
            self.seen.setdefault(p.pid, p)
        return found

    def raylet(self, node: int):
        """The raylet process of node ``node`` (0: head, 1: the second node)."""
        import psutil

        top = psutil.Process(self.procs[node].pid)
        self._scan()
        for p in top.children(recursive=True):
            with contextlib.suppress(psutil.NoSuchProcess):
                if p.name() == "raylet":
                    return p
        raise LookupError(f"node {node} has no raylet")

    def node_id(self, node: int) -> str:
        return self._raylet_flag(node, "--node_id")

    def node_ip(self, node: int) -> str:
        """The IP Ray gave the node (this machine's address: Ray replaces 127.0.0.1 by it)."""
        return self._raylet_flag(node, "--node_ip_address")

    def _raylet_flag(self, node: int, flag: str) -> str:
        return next(a.split("=", 1)[1] for a in self.raylet(node).cmdline() if a.startswith(f"{flag}="))

    def workers(self, node: int) -> list:
        """Node ``node``'s Ray worker processes (actors and idle workers; not its agents)."""
        import psutil

        agents = ("ray::DashboardAgent", "ray::RuntimeEnvAgent")
        found = []
        for p in self.raylet(node).children():
            with contextlib.suppress(psutil.NoSuchProcess):
                title = " ".join(p.cmdline())
                if title.startswith("ray::") and not title.startswith(agents):
                    found.append(p)
        self._scan()
        return found

    def stop(self) -> list[str]:
        """Stop both nodes; returns the processes left alive (``pid cmdline``), which should be none."""
        import shutil
        import signal
        import time

        import psutil

        self._scan()
        groups = [p.pid for p in self.procs]
        for sig, wait in ((signal.SIGTERM, 15.0), (signal.SIGKILL, 10.0)):
            for group in reversed(groups):
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(group, sig)
            if sig == signal.SIGKILL:
                for p in self._alive(groups):
                    with contextlib.suppress(psutil.NoSuchProcess):
                        p.kill()  # ours (seen under our nodes), whatever group it moved to
            end = time.monotonic() + wait
            while self._alive(groups) and time.monotonic() < end:
                time.sleep(0.2)
            if not self._alive(groups):
                break
        for proc in self.procs:
            with contextlib.suppress(Exception):
                proc.wait(timeout=5)
        left = [f"{p.pid} {' '.join(p.cmdline())[:200]}" for p in self._alive(groups)]
        shutil.rmtree(self.temp_dir, ignore_errors=True)
        return left

    def _alive(self, groups: list[int]) -> list:
        import psutil

        alive = {}
        for p in self.seen.values():
            with contextlib.suppress(psutil.NoSuchProcess):
                if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                    alive[p.pid] = p
        for p in psutil.process_iter():
            with contextlib.suppress(psutil.Error, OSError):
                if p.status() == psutil.STATUS_ZOMBIE:
                    continue
                if os.getpgid(p.pid) in groups or str(self.temp_dir) in " ".join(p.cmdline()):
                    alive[p.pid] = p
        return list(alive.values())


def _answers(port: int) -> bool:
    import socket

    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0):
            return True
    except OSError:
        return False


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_cluster(tmp_path_factory):
    """A real two-node Ray cluster for the module's tests; afterwards no process of it may be left."""
    pytest.importorskip("ray")
    pytest.importorskip("psutil")
    cluster = RayCluster(tmp_path_factory.mktemp("ray_cluster"))
    try:
        cluster.start()
    except BaseException:
        cluster.stop()
        raise
    yield cluster
    left = cluster.stop()
    assert not left, f"the Ray cluster left processes behind: {left}"
