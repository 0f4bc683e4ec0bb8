"""Built-in objects: valid solids at real-world size, regions, deformable."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from grt.geometry.deform import ShapeDeformer
from grt.geometry.validation import mesh_problems
from grt.objects import UnknownObjectError, get_object, list_objects, object_info, object_regions
from grt.objects.shapes import min_face_angles

REQUIRED = {"mug", "bottle", "bowl", "can", "cup", "screwdriver", "hammer", "sugar_box", "spray_bottle",
            "banana", "plug", "drawer_handle", "drawer_pull"}


def test_required_objects_listed():
    assert set(list_objects()) >= REQUIRED


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_object_is_valid_metric_solid(name):
    m = get_object(name)
    assert mesh_problems(m) == [], name
    assert m.volume > 0  # outward
    lo, hi = m.bounds
    assert abs(lo[2]) < 1e-6 and np.allclose((lo[:2] + hi[:2]) / 2, 0, atol=1e-6)
    assert m.extents.min() > 0.005 and m.extents.max() < 0.35, m.extents  # meters, household size
    assert 1000 <= len(m.faces) <= 6500, len(m.faces)
    assert min_face_angles(m).min() > 1.0  # no extreme slivers
    # graspable by a Panda gripper (0.08 m): some extent narrower than 0.07 m, or a thin rim/handle
    assert m.extents.min() < 0.07 or {"rim", "handle"} & set(object_regions(name)), m.extents


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_regions_inside_object_bounds(name):
    m = get_object(name)
    regions = object_regions(name)
    assert regions and object_info(name)["description"]
    for part, box in regions.items():
        assert box.shape == (2, 3) and np.all(box[1] > box[0]), part
        inside = np.all((m.vertices >= box[0]) & (m.vertices <= box[1]), axis=1)
        assert inside.sum() >= 3, f"{name}:{part} holds no vertices"


def test_named_regions_and_copies():
    assert {"handle", "rim"} <= set(object_regions("mug"))
    assert "head" in object_regions("plug")
    a = get_object("mug")
    a.vertices += 1.0
    assert get_object("mug").bounds[0][2] == 0.0  # cache not mutated


@pytest.mark.parametrize("name", ["drawer_handle", "drawer_pull"])
def test_drawer_handle_grasp_on_grip_and_feet_on_front(name):
    m = get_object(name)
    regions = object_regions(name)
    drawer = object_info(name)["drawer"]
    grasp, radius = np.asarray(drawer["grasp"]), drawer["grip_radius"]
    grip = regions["grip"]
    assert np.all((grasp >= grip[0]) & (grasp <= grip[1])), grasp
    dist = trimesh.proximity.closest_point(m, grasp[None])[1][0]
    assert dist <= radius + 1e-3, (dist, radius)  # the grasp point sits on the tube's axis
    for foot in ("left_foot", "right_foot"):
        box = regions[foot]
        assert np.any((grip[0] > box[1]) | (grip[1] < box[0])), f"{name}: grip overlaps {foot}"
        inside = np.all((m.vertices >= box[0]) & (m.vertices <= box[1]), axis=1)
        assert inside.any() and m.vertices[inside, 2].min() < 1e-6, f"{name}:{foot} does not touch z = 0"
    if name == "drawer_handle":  # old region names still work
        assert all(np.array_equal(regions[a], regions[b]) for a, b in
                   (("bar", "grip"), ("left_post", "left_foot"), ("right_post", "right_foot")))


def test_unknown_object_error():
    with pytest.raises(UnknownObjectError) as err:
        get_object("teapot")
    msg = str(err.value)
    assert "teapot" in msg and "mug" in msg and "path" in msg
    with pytest.raises(ValueError):
        object_regions("teapot")


@pytest.mark.parametrize("name", sorted(REQUIRED))
def test_object_deforms_with_a_few_handles(name, rng):
    m = get_object(name)
    v = np.asarray(m.vertices)
    order = np.argsort(v[:, 2])
    d = ShapeDeformer(m, order[-3:], order[:60], align=False)
    theta = 0.01 * rng.standard_normal((3, 3))
    out = d.vertices(theta)
    assert np.all(np.isfinite(out))
    target = d.frame.to_metric(d.v0_unit[order[-3:]] + theta)
    assert np.abs(out[order[-3:]] - target).max() < 1e-8


def test_the_listing_says_which_task_each_object_is_for(capsys):
    """``python -m grt.objects`` names each object's task (issue 40: ``plug`` is listed but is no insertion plug)."""
    from grt.cli.objects import main

    main([])
    rows = {line.split()[0]: line.split()[1] for line in capsys.readouterr().out.splitlines()[1:] if line.split()}
    assert rows["usb_plug"] == rows["round_peg"] == "insertion"
    assert rows["drawer_handle"] == rows["drawer_pull"] == "drawer"
    assert rows["plug"] == rows["mug"] == "grasp"
    assert object_info("plug")["task"] == "grasp"


def test_export_writes_every_object_and_never_replaces_a_file_unasked(tmp_path, capsys):
    """``--export DIR``: every object as DIR/<name>.obj; a folder that cannot be made, or one holding a file of
    an object's name (the user's own mug.obj), is one line and exit 2, nothing written (before, a traceback,
    and the file replaced); ``--overwrite`` replaces them."""

    from grt.cli.objects import main

    main(["--export", str(tmp_path / "all")])
    assert sorted(p.stem for p in (tmp_path / "all").iterdir()) == sorted(list_objects())
    exported = trimesh.load(tmp_path / "all" / "mug.obj", force="mesh")
    assert exported.is_watertight and abs(exported.volume - get_object("mug").volume) < 1e-9
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "mug.obj").write_text("the user's own mug\n")
    capsys.readouterr()
    for folder in (str(mine), str(tmp_path / "file.txt" / "sub")):
        (tmp_path / "file.txt").write_text("a file, not a folder\n")
        with pytest.raises(SystemExit) as info:
            main(["--export", folder])
        err = capsys.readouterr().err.strip().splitlines()
        assert info.value.code == 2 and len(err) == 1 and err[0].startswith("error: --export "), err
    assert (mine / "mug.obj").read_text() == "the user's own mug\n"
    assert sorted(p.name for p in mine.iterdir()) == ["mug.obj"]
    main(["--export", str(mine), "--overwrite"])
    assert len(list(mine.iterdir())) == len(list_objects())
