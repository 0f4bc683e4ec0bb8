"""policy=remote and the grt-policy/1 server (grt/policy_server.py): protocol, handshake checks, failures.

Servers run in a thread of the test process (fast) or, where a test kills one, as a separate process
(``_remote_toy.py``). The trials are :class:`_remote_toy.PointMassSession`'s (a real EpisodeSession on a
toy task), so that the pool tests take seconds.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from grt.policies.base import GraspObservation, PolicyInterrupted, PolicyServerError, PolicyUnavailable
from grt.policies.remote import PolicyReplyError, RemoteBatchedPolicy, RemoteGraspPolicy, connect
from grt.policy_server import PolicyServer, ProtocolError, pack, unpack

HERE = Path(__file__).parent
sys.path.insert(0, str(HERE))
from _remote_toy import GreedyPolicy, PointMassSession  # noqa: E402

SPEC = dict(kind="batched", task="point_mass", obs={"state": [4]}, action_size=2, name="greedy", version="1")


def serve(port: int = 0, **kwargs) -> PolicyServer:
    """A server of the greedy policy (or of ``act=...``) in a thread of this process."""
    args = {**SPEC, "act": GreedyPolicy().act, **kwargs}
    return PolicyServer(port=port, **args).__enter__()


@pytest.fixture(scope="module")
def u_mesh():
    import trimesh

    return trimesh.creation.box((0.06, 0.03, 0.05))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# ------------------------------------------------------------------------------------------- protocol
@pytest.mark.parametrize("dtype", ["<f4", "<f8", "<i8", "|u1", "|b1", ">f4"])
def test_arrays_cross_the_wire_bit_exact(dtype):
    a = (np.arange(24).reshape(2, 3, 4) % 7).astype(dtype)
    b = unpack(pack({"type": "x", "a": a, "n": np.float32(1.5)}))
    assert b["a"].dtype == a.dtype and b["a"].shape == a.shape and np.array_equal(a, b["a"]) and b["n"] == 1.5
    b["a"][0] = 1  # writable: a policy may work in place


def test_no_pickle_no_objects():
    with pytest.raises(ProtocolError, match="numeric arrays only"):
        pack({"type": "x", "a": np.array([object()], dtype=object)})
    for dtype, raw in (("|O", b"\0" * 8), ("<f4", b"\0" * 3), ("[('a', '<f4')]", b"\0" * 4)):
        forged = msgpack.packb({"type": "x", "a": msgpack.ExtType(1, msgpack.packb([dtype, [1], raw]))})
        with pytest.raises(ProtocolError):
            unpack(forged)
    with pytest.raises(ProtocolError, match="map with a 'type'"):
        unpack(msgpack.packb([1, 2]))
    with pytest.raises(ProtocolError, match="binary"):
        unpack("text")


def test_the_server_module_imports_no_simulator_torch_or_grt(tmp_path):
    """It is installed alone in a policy's environment: numpy, websockets and msgpack only."""
    code = ("import sys, policy_server; heavy = {'torch', 'sapien', 'mani_skill', 'hydra', 'omegaconf', 'trimesh',"
            " 'scipy', 'grt'} & {m.split('.')[0] for m in sys.modules}; print(sorted(heavy)); sys.exit(bool(heavy))")
    (tmp_path / "policy_server.py").write_text((HERE.parents[1] / "grt" / "policy_server.py").read_text())
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr


# ------------------------------------------------------------------------------------------- handshake
def test_a_batched_policy_served_acts_as_in_process():
    with serve() as server:
        policy = connect(server.url)
        assert isinstance(policy, RemoteBatchedPolicy) and policy.num_actions == 2
        policy.check("point_mass", {"state": (4,), "extra": (3,)}, 2)  # extra groups are not sent
        obs = {"state": np.random.default_rng(0).uniform(-1, 1, (5, 4)).astype(np.float32), "extra": np.ones((5, 3))}
        policy.reset(3)
        assert np.array_equal(policy.act(obs), GreedyPolicy().act(obs))
        policy.close()


@pytest.mark.parametrize(("task", "spec", "actions", "message"), [
    ("insertion", {"state": (4,)}, 2, "serves greedy 1 (batched policy for 'point_mass'), but the run's task is "
                                      "'insertion'"),
    ("point_mass", {"state": (24,)}, 2, "expects observation 'state' of shape (4,), the task gives (24,)"),
    ("point_mass", {"cloud": (500, 3)}, 2, "reads observation 'state' of shape (4,), which the task does not give "
                                          "(it gives cloud (500, 3))"),
    ("point_mass", {"state": (4,)}, 6, "outputs 2 actions, the task takes 6")])
def test_a_handshake_mismatch_names_both_sides(task, spec, actions, message):
    with serve() as server, pytest.raises(PolicyServerError, match=re.escape(message)):
        connect(server.url).check(task, spec, actions)


def test_no_server_bad_token_and_bad_url_are_one_line_user_errors():
    url = f"ws://127.0.0.1:{free_port()}"
    with pytest.raises(PolicyServerError, match=f"no policy server at {url}.*python -m grt.serve"):
        connect(url)
    with pytest.raises(PolicyServerError, match="not a WebSocket URL"):
        connect("http://127.0.0.1:1")
    with serve(token="s3cret") as server:
        for token in (None, "wrong"):
            with pytest.raises(PolicyServerError, match="refused the connection: bad or missing token"):
                connect(server.url, token=token)
        assert connect(server.url, token="s3cret").server["name"] == "greedy"


def test_binds_this_machine_only_by_default():
    with serve() as server:
        assert server.host == "127.0.0.1" and server.url.startswith("ws://127.0.0.1:")


def test_a_server_stopped_before_it_served_closes_its_port_at_once():
    """A Ctrl-C between ``grt.serve``'s URL line and its loop: the shutdown waited forever for a loop that
    never ran (the server hung until killed)."""
    server = PolicyServer(act=lambda obs: obs["state"][:, :2], kind="batched", task="t", obs={"state": (3,)},
                          action_size=2, port=0)
    stopper = threading.Thread(target=server.shutdown, daemon=True)
    stopper.start()
    stopper.join(timeout=10)
    assert not stopper.is_alive(), "shutdown() of a server that never served did not return"
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", server.port), timeout=2).close()


# ------------------------------------------------------------------------------------------- replies
def test_timeouts_errors_and_malformed_replies_are_reply_errors():
    state = {"state": np.zeros((1, 4), np.float32)}
    slow = threading.Event()

    def act(obs):
        if slow.is_set():
            time.sleep(0.6)
        mode = int(obs["state"][0, 0])
        replies = {0: np.zeros((1, 2)), 1: np.zeros((1, 3)), 2: np.full((1, 2), np.nan),
                   4: np.array([[object(), 1]], dtype=object)}
        if mode not in replies:
            raise ZeroDivisionError("the policy itself failed")
        return replies[mode]

    with serve(act=act) as server:
        policy = connect(server.url, timeout=0.3)
        for mode, message in ((1, r"action of shape \(1, 3\), expected \(1, 2\)"), (2, "non-finite action"),
                              (3, "answered with an error: ZeroDivisionError"),
                              (4, "answered with an error: ProtocolError: cannot send an array of dtype object")):
            with pytest.raises(PolicyReplyError, match=message):
                policy.act({"state": np.full((1, 4), mode, np.float32)})
        slow.set()
        with pytest.raises(PolicyInterrupted, match=r"no reply from .* within 0.3 s \(policy.timeout"):
            policy.act(state)  # a stalled server: no outcome of the trial's, which is re-run (issue 40)
        slow.clear()
        time.sleep(0.5)  # the late reply arrives; the next request (on a new connection) must not take it
        with pytest.raises(PolicyReplyError, match=r"action of shape \(1, 3\)"):
            policy.act({"state": np.full((1, 4), 1, np.float32)})


def test_a_stalled_server_reruns_the_trial_and_stops_the_evaluation_if_it_stays_silent(u_mesh, tmp_path, toy_path):
    """Issue 40: a reply later than ``policy.timeout`` made the trial a ``sim_error`` (a candidate unscored, the
    table normal). It is no outcome of the trial's: the trial is re-run, so a stall changes no score; a server
    that stays silent stops the evaluation in one line (a red-team run then resumes, every trial scored)."""
    seeds = list(range(6))
    session = PointMassSession(GreedyPolicy())
    session.load_object(u_mesh, [])
    local = [(t.seed, t.mode, t.score) for t in (session.run_trial(s) for s in seeds)]
    stalls, greedy = {"left": 1, "always": False}, GreedyPolicy()

    def act(obs):
        if stalls["always"] or stalls["left"] > 0:
            stalls["left"] -= 1
            time.sleep(0.6)
        return greedy.act(obs)

    with serve(act=act) as server, _evaluator({"_target_": "grt.policies.remote.connect", "url": server.url,
                                               "timeout": 0.3, "retry_wait": 0.1}, u_mesh, tmp_path,
                                              workers=1) as ev:
        (result,) = ev.evaluate([u_mesh], seeds)
        assert stalls["left"] == 0 and [(t.seed, t.mode, t.score) for t in result.trials] == local
        stalls["always"] = True
        with pytest.raises(PolicyServerError, match=r"interrupted 3 times in a row: no reply from .* within 0.3 s "
                                                    r"\(policy.timeout.*the evaluation stopped"):
            ev.evaluate([u_mesh], seeds)
    with pytest.raises(PolicyServerError, match=r"policy.timeout=0: the seconds to wait .* must be > 0"):
        connect("ws://127.0.0.1:1", timeout=0)  # every trial lost to a zero wait (exit code 0 before)


def test_a_grasp_planner_served():
    pose = np.eye(4)
    pose[:3, 3] = [0.0, 0.0, 0.1]

    def plan(points, viewpoints, table_z, seed, context):
        assert points.shape == viewpoints.shape == (10, 3) and context is None
        if seed == 1:
            return [{"pose": np.eye(3), "width": 0.02, "score": 1.0}]
        return [{"pose": pose, "width": 0.03, "score": 0.9, "info": {"n": len(points), "obj": object()}}]

    with PolicyServer(plan=plan, kind="grasp", task="grasp", context_radius=0.25, name="toy") as server:
        policy = connect(server.url)
        assert isinstance(policy, RemoteGraspPolicy) and policy.context_radius == 0.25
        obs = GraspObservation(np.zeros((10, 3)), np.ones((10, 3)), 0.0)
        (grasp,) = policy.plan(obs, 0)
        assert np.array_equal(grasp.pose, pose) and grasp.width == 0.03 and grasp.info == {"n": 10}
        with pytest.raises(PolicyReplyError, match=r"grasp 0 needs a finite \(4, 4\) pose"):
            policy.plan(obs, 1)
        with pytest.raises(PolicyServerError, match="the run's task is 'insertion'"):
            policy.check("insertion", {"state": (24,)}, 6)


# ------------------------------------------------------------------------------------------- reconnection
def test_reconnects_to_the_same_policy_and_refuses_another():
    port = free_port()
    server = serve(port)
    policy = connect(server.url, retries=4, retry_wait=0.1)
    policy.reset(0)
    server.__exit__()
    with pytest.raises(PolicyInterrupted, match="lost"):  # the episode's state is gone: re-run the trial
        policy.act({"state": np.zeros((1, 4), np.float32)})
    with serve(port):
        policy.reset(0)  # back: the next trial reconnects
    with pytest.raises(PolicyInterrupted):
        policy.reset(0)
    start = time.perf_counter()
    with pytest.raises(PolicyUnavailable, match=r"is down: 5 connection attempts over 1.5 s failed"):
        policy.reset(0)
    assert time.perf_counter() - start < 5
    policy.close()
    with serve(port, name="another"), pytest.raises(PolicyUnavailable, match="came back as another 1"):
        policy.reset(0)


# ------------------------------------------------------------------------------------------- worker pool
def _start_toy_server(port: int, delay: float) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE.parents[1]), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen([sys.executable, str(HERE / "_remote_toy.py"), str(port), str(delay)],
                            stdout=subprocess.PIPE, text=True, cwd=HERE.parents[1], env=env)
    assert proc.stdout.readline().strip() == f"ws://127.0.0.1:{port}"
    return proc


def _evaluator(policy: dict, u_mesh, tmp_path, workers: int = 2):
    from grt.evaluators.sim import SimEvaluator

    task = {"name": "point_mass", "session": {"_target_": "_remote_toy.PointMassSession"}}
    return SimEvaluator(task, policy, workers=workers, nominal=u_mesh, cache_dir=str(tmp_path / "coacd"),
                        progress=False)


@pytest.fixture
def toy_path(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))  # spawned workers inherit sys.path


def test_server_restart_mid_evaluation_reruns_the_trials_in_flight(u_mesh, tmp_path, toy_path):
    """Two workers, one connection each; the server dies and comes back: same outcomes as in process."""
    port, seeds = free_port(), list(range(16))
    session = PointMassSession(GreedyPolicy())
    session.load_object(u_mesh, [])
    local = [session.run_trial(s) for s in seeds]
    assert {t.mode for t in local} == {"success", "timeout"}  # a test that can fail
    server = _start_toy_server(port, delay=0.03)
    restarted = []
    try:
        with _evaluator({"_target_": "grt.policies.remote.connect", "url": f"ws://127.0.0.1:{port}",
                         "retry_wait": 0.2, "retries": 6}, u_mesh, tmp_path) as ev:
            ev.evaluate([u_mesh], seeds[:2])  # workers up
            threading.Timer(0.6, server.kill).start()
            threading.Timer(1.0, lambda: restarted.append(_start_toy_server(port, 0.03))).start()
            remote = ev.evaluate([u_mesh], seeds)[0]
            assert restarted  # the evaluation went on past the restart
    finally:
        for proc in [server, *restarted]:
            proc.kill()
            proc.wait()
    assert [(t.seed, t.mode, t.score) for t in remote.trials] == [(t.seed, t.mode, t.score) for t in local]


def test_a_server_that_stays_down_stops_the_evaluation(u_mesh, tmp_path, toy_path):
    port = free_port()
    server = _start_toy_server(port, delay=0.02)
    try:
        with _evaluator({"_target_": "grt.policies.remote.connect", "url": f"ws://127.0.0.1:{port}",
                         "retry_wait": 0.1, "retries": 2}, u_mesh, tmp_path, workers=1) as ev:
            ev.evaluate([u_mesh], [0])
            threading.Timer(0.3, server.kill).start()
            with pytest.raises(PolicyServerError, match="is down: 3 connection attempts.*the evaluation stopped"):
                ev.evaluate([u_mesh], list(range(40)))
    finally:
        server.kill()
        server.wait()


def test_the_token_is_never_written_into_the_run_folder(tmp_path, monkeypatch):
    from omegaconf import OmegaConf

    from grt.config import make_plan
    from grt.runfolder.record import RUN_CONFIG, save_run_config
    from tests.runner.conftest import compose_run

    monkeypatch.setenv("GRT_POLICY_TOKEN", "s3cret-value")
    cfg = compose_run(["policy=remote", f"paths.output_dir={tmp_path}"])
    assert cfg.policy.token == "s3cret-value"
    save_run_config(make_plan(cfg))
    assert "s3cret-value" not in (tmp_path / RUN_CONFIG).read_text()
    saved = OmegaConf.load(tmp_path / RUN_CONFIG)["config"]
    assert saved.policy.token == "s3cret-value"  # a resume reads it from the environment
