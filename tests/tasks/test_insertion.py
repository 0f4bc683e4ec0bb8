"""GRT-Insert-v1: the socket fits its plug, episodes are seeded, failures are named, bad plugs refused."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grt.objects import get_object
from grt.tasks.socket import PlugFitError, build_socket, head_outline

PLUGS = ["usb_plug", "round_peg"]


@pytest.mark.parametrize("name", PLUGS)
def test_socket_hole_fits_the_head_with_the_clearance(name):
    plug = get_object(name)
    sock = build_socket(plug, 0.012, clearance=0.0004)
    head = head_outline(plug, 0.012) - sock.center
    # every head vertex is inside the hole, 0.4 mm from its walls
    edges = np.roll(sock.hole, -1, axis=0) - sock.hole
    normals = np.stack([edges[:, 1], -edges[:, 0]], 1) / np.linalg.norm(edges, axis=1, keepdims=True)
    signed = np.einsum("jek,ek->je", head[:, None, :] - sock.hole[None, :, :], normals)  # < 0: inside
    assert (-signed.max(axis=1)).min() == pytest.approx(0.0004, abs=2e-5)
    assert sock.depth == pytest.approx(0.013)
    for part in sock.parts[:-1]:  # every wall piece lies outside the hole (the last one is its floor)
        inside = np.einsum("jek,ek->je", part[:, None, :2] - sock.hole[None], normals).max(axis=1) < -1e-9
        assert not inside.any()


def test_a_plug_without_a_head_is_refused():
    with pytest.raises(PlugFitError, match="head_length"):
        build_socket(trimesh.creation.box([0.02, 0.01, 0.04]), head_length=-0.05)


def test_unknown_plug_geometry_asks_for_the_config_keys():
    from grt.tasks.insertion import plug_geometry

    assert plug_geometry("usb_plug", None, None) == (0.012, 0.030)
    with pytest.raises(PlugFitError, match="task.session.head_length"):
        plug_geometry("/tmp/my_plug.obj", None, None)
    # 'plug' is built in, but for grasping (it lies on its side): the message says so and names the plugs
    with pytest.raises(PlugFitError, match=r"'plug' is a built-in object of the grasp task .* the insertion task's "
                                           r"built-in plugs are round_peg, usb_plug"):
        plug_geometry("plug", None, None)


def test_a_plug_too_wide_for_the_gripper_is_refused_before_simulation():
    from grt.tasks.insertion import InsertionSession

    wide = get_object("usb_plug")
    wide.apply_scale([1.0, 9.0, 1.0])
    with pytest.raises(PlugFitError, match="wide across the fingers"):
        InsertionSession.check_object(wide, socket_object="usb_plug")
    InsertionSession.check_object(get_object("usb_plug"), socket_object="usb_plug")  # the nominal passes


@pytest.fixture(scope="module")
def servo_session():
    pytest.importorskip("mani_skill")
    from grt.evaluators.collision import make_collision
    from grt.policies.servo import ServoInsertionPolicy
    from grt.tasks.insertion import InsertionSession

    plug = get_object("usb_plug")
    parts = make_collision("coacd", None, None, None, 64).parts(plug)
    session = InsertionSession(ServoInsertionPolicy(), socket_object="usb_plug", cloud_points=64)
    session.load_object(plug, parts)
    yield session, plug, parts
    session.close()


@pytest.mark.sim
def test_servo_inserts_the_nominal_plug_and_trials_repeat(servo_session):
    session, _, _ = servo_session
    outcomes = [session.run_trial(s) for s in (3, 4, 5)]
    assert [o.mode for o in outcomes] == ["success"] * 3, [o.info for o in outcomes]
    assert all(o.info["tip_to_floor"] < 0.003 and o.info["steps"] < 256 for o in outcomes)
    again = session.run_trial(4)
    assert again.info["steps"] == outcomes[1].info["steps"]
    assert again.info["keypoint_error"] == pytest.approx(outcomes[1].info["keypoint_error"], abs=1e-6)
    obs = session.observe()
    assert obs["state"].shape == (24,) and obs["cloud"].shape == (64, 3)


@pytest.mark.sim
def test_a_plug_shifted_in_the_grip_is_named_a_failure(servo_session):
    """A plug whose grip bulges 7 mm on one side sits off-center in the fingers: the servo misses."""
    from grt.evaluators.collision import make_collision

    session, plug, _ = servo_session
    bent = plug.copy()
    v = bent.vertices.copy()
    grip = v[:, 2] > 0.013
    v[grip & (v[:, 1] > 0), 1] += 0.007
    bent.vertices = v
    session.load_object(bent, make_collision("coacd", None, None, None, 64).parts(bent))
    try:
        modes = {session.run_trial(s).mode for s in (3, 4)}
    finally:
        session.load_object(plug, servo_session[2])
    assert "success" not in modes and modes <= {"jammed", "misaligned", "dropped", "timeout"}


@pytest.mark.sim
def test_the_grip_observation_shows_how_the_plug_sits_in_the_hand(servo_session):
    """Near zero for the nominal plug; a plug with a bulged grip sits millimetres off in the fingers, and
    the grip-aware servo, which corrects its target by it, still inserts the nominal plug."""
    from grt.evaluators.collision import make_collision
    from grt.policies.servo import ServoInsertionPolicy

    session, plug, parts = servo_session

    def grip_at_rest(seed: int) -> np.ndarray:
        session.reset(seed, rebuild=True)
        for _ in range(10):
            obs, *_ = session.step(np.zeros(6, np.float32))
        return obs["grip"]

    nominal = grip_at_rest(3)
    assert nominal.shape == (6,) and np.abs(nominal[:3]).max() < 2e-3 and np.abs(nominal[3:]).max() < 0.1
    bent = plug.copy()
    v = bent.vertices.copy()
    v[(v[:, 2] > 0.013) & (v[:, 1] > 0), 1] += 0.007
    bent.vertices = v
    session.load_object(bent, make_collision("coacd", None, None, None, 64).parts(bent))
    try:
        shifted = grip_at_rest(3)
    finally:
        session.load_object(plug, parts)
    assert np.linalg.norm(shifted[:3] - nominal[:3]) > 2e-3, (nominal, shifted)
    blind = session.policy
    session.policy = ServoInsertionPolicy(grip=True)
    try:
        assert [session.run_trial(s).mode for s in (3, 4)] == ["success"] * 2
    finally:
        session.policy = blind


@pytest.mark.sim
@pytest.mark.parametrize("name", ["insertion_state", "insertion_pcd"])
def test_shipped_checkpoints_load_and_insert(name, servo_session):
    from grt.policies.rsl_rl import RslRlPolicy
    from grt.tasks.insertion import InsertionSession

    policy = RslRlPolicy(f"grt/policies/checkpoints/{name}.pt", task="insertion")
    assert policy.config["task"] == "insertion" and policy.config["train_cfg"]["algorithm"]["class_name"] == "PPO"
    session = InsertionSession(policy, socket_object="usb_plug")  # checks the policy's observations
    _, plug, parts = servo_session
    session.load_object(plug, parts)
    try:
        modes = [session.run_trial(s).mode for s in (11, 12, 13, 14)]
    finally:
        session.close()
    assert modes.count("success") >= 3, modes


@pytest.mark.sim
@pytest.mark.slow
def test_ppo_iterations_on_the_real_insertion_env_update_the_policy(tmp_path):
    from grt.evaluators.collision import make_collision
    from grt.policies.rsl_rl import RslRlPolicy
    from grt.rl.train import TrainSpec, export_policy, train
    from grt.rl.vec_env import Shape, TaskVecEnv
    from tests.rl.conftest import TRAIN_CFG

    plug = get_object("usb_plug")
    task = {"name": "insertion",
            "session": {"_target_": "grt.tasks.insertion.InsertionSession", "socket_object": "usb_plug",
                        "cloud_points": 0}}
    env = TaskVecEnv(task, [Shape.of(plug, make_collision("coacd", None, None, None, 64).parts(plug))],
                     num_envs=2, workers=0, seed=0, max_steps=16)
    cfg = {**TRAIN_CFG, "num_steps_per_env": 8}
    train(env, TrainSpec(cfg, tmp_path / "a", "insertion", task, iterations=1))
    before = torch_load(tmp_path / "a" / "last.pt")["actor_state_dict"]
    train(env, TrainSpec(cfg, tmp_path / "a", "insertion", task, iterations=3))
    env.close()
    after = torch_load(tmp_path / "a" / "last.pt")["actor_state_dict"]
    changed = [k for k in before if not (before[k] == after[k]).all()]
    assert any("mlp" in k for k in changed), "PPO did not update the actor"
    policy = RslRlPolicy(str(export_policy(tmp_path / "a" / "last.pt", tmp_path / "p.pt")), task="insertion")
    assert policy.act({"state": np.zeros((1, 24), np.float32)}).shape == (1, 6)


def torch_load(path):
    import torch

    return torch.load(path, map_location="cpu", weights_only=False)
