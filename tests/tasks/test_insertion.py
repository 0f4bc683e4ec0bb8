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
    from grt.eval.collision import make_collision
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
    from grt.eval.collision import make_collision

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
