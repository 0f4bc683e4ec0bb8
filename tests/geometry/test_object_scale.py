"""Units: ``object_scale`` scales the object at load (vertex order kept), and an object above 1 m or below 5 mm
across is refused before any simulation by ``grt.run``, ``grt.evaluate`` and ``grt.select``, naming the key."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from grt.geometry.mesh import MeshError, check_object_size, load_mesh
from grt.objects import get_object
from grt.tasks import preflight
from grt.tasks.base import TaskInputError

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def mm_mesh(tmp_path_factory) -> Path:
    """The mug written in millimetres (119 mm across, so "119 m" read as meters)."""
    path = tmp_path_factory.mktemp("units") / "mug_mm.obj"
    mug = get_object("mug")
    mug.apply_scale(1000.0)
    mug.export(path)
    return path


def test_a_millimetre_mesh_is_refused_naming_the_unit_and_the_key(mm_mesh):
    with pytest.raises(MeshError, match=r"119 m across.*millimetres\? set object_scale=0\.001"):
        check_object_size(load_mesh(mm_mesh))


def test_object_scale_makes_it_meters_in_the_same_vertex_order(mm_mesh):
    raw = load_mesh(mm_mesh)
    mesh = load_mesh(mm_mesh, scale=0.001)
    check_object_size(mesh)
    np.testing.assert_allclose(mesh.vertices, raw.vertices * 0.001)
    np.testing.assert_array_equal(mesh.faces, raw.faces)
    assert mesh.metadata["grt_source"] == str(mm_mesh)


def test_a_tiny_object_and_a_bad_scale_are_refused():
    with pytest.raises(MeshError, match=r"less than 5 mm.*object_scale=1000"):
        check_object_size(load_mesh("mug", scale=0.001))
    with pytest.raises(MeshError, match="object_scale=0"):
        load_mesh("mug", scale=0)


def test_object_scale_is_refused_where_the_task_reloads_the_mesh_file(mm_mesh):
    task = {"name": "insertion", "session": {"_target_": "grt.tasks.base.TaskSession", "socket_object": str(mm_mesh)}}
    with pytest.raises(TaskInputError, match="task.session.socket_object"):
        preflight(task, None, load_mesh(mm_mesh, scale=0.001), object_scale=0.001)


def test_evaluate_and_select_refuse_it_before_any_simulation(mm_mesh, tmp_path):
    from grt.cli.evaluate import evaluate
    from grt.cli.select import select
    from tests.runner.conftest import compose_run

    cfg = compose_run([f"object={mm_mesh}", "budget=smoke"], config_name="evaluate")
    with pytest.raises(MeshError, match="object_scale=0.001"):
        evaluate(cfg, tmp_path / "eval")  # the default evaluator is the simulator: the mesh is refused first
    with pytest.raises(MeshError, match="object_scale=0.001"):
        select(str(mm_mesh), "grasp it", selector=None, out_dir=tmp_path / "select")
    assert not (tmp_path / "eval").exists() and not (tmp_path / "select" / "handles.json").exists()


@pytest.mark.parametrize("module", ["grt.run", "grt.select"])
def test_the_clis_say_it_in_one_line_with_exit_code_2(module, mm_mesh, tmp_path):
    args = ["task.session._target_=tests.runner._toy_run.ToyTaskSession"] if module == "grt.run" else []
    proc = subprocess.run([sys.executable, "-m", module, f"object={mm_mesh}", *args, f"hydra.run.dir={tmp_path}"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "WANDB_MODE": "disabled"})
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out
    assert "Traceback" not in out and "object_scale=0.001" in out
    assert not (tmp_path / "journal.jsonl").exists() and not (tmp_path / "handles.json").exists()
