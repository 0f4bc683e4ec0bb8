"""Your own plug or drawer handle (issue 33 §2): the user's object is checked (not the built-in), a plug's
tip must be at z = 0, the gripper limit is named as applied (76 mm), and selector=manual derives the regions
of a user's object from the task's geometry keys."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hydra.utils import instantiate

from grt.geometry.mesh import load_mesh
from grt.objects import get_object
from grt.tasks.drawer import DrawerSession, HandleFitError
from grt.tasks.insertion import InsertionSession, PlugFitError
from tests.runner.conftest import compose_run


def _tall_plug(tmp_path: Path, shift: float = 0.0) -> Path:
    plug = get_object("usb_plug")
    plug.vertices[:, 2] *= 1.5  # 63 mm tall: a grip at 50 mm is on its body (the built-in is 42 mm)
    plug.apply_translation([0, 0, shift])
    path = tmp_path / f"plug{shift:+.3f}.obj"
    plug.export(path)
    return path


def test_a_user_plug_with_an_odd_grip_height_is_checked_itself(tmp_path):
    path = str(_tall_plug(tmp_path))
    keys = dict(socket_object=path, head_length=0.018, grip_height=0.05)
    InsertionSession.check_object(load_mesh(path), **keys)  # the user's plug has a surface at 50 mm
    with pytest.raises(PlugFitError, match="grip_height=0.05"):  # the built-in 42 mm plug has none there
        InsertionSession.check_object(get_object("usb_plug"), socket_object="usb_plug", head_length=0.012,
                                      grip_height=0.05)


def test_a_user_plug_session_builds_its_env_around_the_users_plug(tmp_path):
    pytest.importorskip("mani_skill")
    path = str(_tall_plug(tmp_path))
    session = InsertionSession(None, socket_object=path, head_length=0.018, grip_height=0.05, cloud_points=0)
    try:  # the env's first object is the user's plug: the 42 mm built-in would have no grip at 50 mm
        assert session.unwrapped.object_meshes[0].extents[2] == pytest.approx(0.063, abs=1e-3)
    finally:
        session.close()


def test_a_plug_whose_tip_is_not_at_z0_is_refused_with_the_shift(tmp_path):
    path = str(_tall_plug(tmp_path, shift=-0.006))
    with pytest.raises(PlugFitError, match=r"tip is at z = -6.0 mm.*move the mesh up by 6.0 mm"):
        InsertionSession.check_object(load_mesh(path), socket_object=path, head_length=0.018, grip_height=0.05)


def test_the_gripper_limit_named_is_the_one_applied():
    wide = get_object("usb_plug")
    wide.vertices[:, 1] *= 7.8  # 82 mm across the fingers
    with pytest.raises(PlugFitError, match=r"widest grip the task accepts is 76 mm \(the Panda opens 80 mm"):
        InsertionSession.check_object(wide, socket_object="usb_plug")


def test_manual_handles_on_a_user_plug_come_from_head_length(tmp_path):
    path = _tall_plug(tmp_path)
    cfg = compose_run(["task=insertion", "selector=manual", f"object={path}", "task.session.head_length=0.018",
                       "task.session.grip_height=0.05", f"paths.output_dir={tmp_path}"])
    mesh = load_mesh(path)
    picked = instantiate(cfg.selector).select(mesh, "")
    z = np.asarray(mesh.vertices)[:, 2]
    assert len(picked.handles) == 8 and (z[picked.handles] >= 0.018).all()  # on the grip
    assert len(picked.anchors) > 3 and (z[picked.anchors] <= 0.018).all()  # on the connector head
    builtin = compose_run(["task=insertion", "selector=manual", f"paths.output_dir={tmp_path}"])
    usb = load_mesh("usb_plug")
    same = instantiate(builtin.selector).select(usb, "")  # the built-in's named regions, as before
    legacy = instantiate(builtin.selector, handle_regions=["usb_plug:grip"], anchor_regions=["usb_plug:head"])
    assert same.handles.tolist() == legacy.select(usb, "").handles.tolist()
    no_head = compose_run(["task=insertion", "selector=manual", f"object={path}", f"paths.output_dir={tmp_path}"])
    with pytest.raises(ValueError, match="set task.session.head_length"):
        instantiate(no_head.selector).select(mesh, "")


def test_a_user_drawer_handle_gets_manual_regions_and_its_checks(tmp_path):
    handle = get_object("drawer_pull")
    path = tmp_path / "pull.obj"
    handle.export(path)
    cfg = compose_run(["task=drawer", "selector=manual", f"object={path}", "task.session.grasp_point=[0,0,0.032]",
                       f"paths.output_dir={tmp_path}"])
    mesh = load_mesh(path)
    picked = instantiate(cfg.selector).select(mesh, "")
    v = np.asarray(mesh.vertices)
    assert (v[picked.handles, 2] >= 0.024).all() and (v[picked.anchors, 2] <= 0.008).all()
    assert (v[picked.anchors, 0] < 0).any() and (v[picked.anchors, 0] > 0).any()  # both feet
    floating = handle.copy()
    floating.apply_translation([0, 0, 0.006])
    with pytest.raises(HandleFitError, match="6 mm in front of its mounting plane"):
        DrawerSession.check_object(floating, handle_object=str(path), grasp_point=[0, 0, 0.032])
