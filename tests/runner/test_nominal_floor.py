"""A run whose nominal score S0 is below ``task.nominal_floor`` stops right after the nominal evaluation (one
line, exit code 2, the nominal record journaled); ``resume=DIR task.nominal_floor=...`` goes on from there,
and the finished run's ``nominal.obj`` has the vertex order and faces of every CrashShape.

The runs are real ``python -m grt.run`` processes with the toy evaluator of ``_toy_run`` (no simulator),
whose S0 is 1.0: a floor of 1.5 stops it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from grt.geometry.mesh import load_mesh
from grt.geometry.prepare import MeshSettings
from grt.scores import (
    BINARY_FLOOR,
    NominalFloorError,
    ScoreConfigError,
    ScoreSpec,
    check_nominal_floor,
    nominal_floor,
)
from grt.selectors.base import HandleSet
from tests.runner._toy_run import TOY

ROOT = Path(__file__).resolve().parents[2]


def grt_run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.run", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "WANDB_MODE": "disabled"})


def journal(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "journal.jsonl").read_text().splitlines()]


@pytest.mark.parametrize(("task", "floor"), [({}, BINARY_FLOOR), ({"score": "success"}, BINARY_FLOOR),
                                             ({"score": "opening", "score_unit": "m"}, None),
                                             ({"score": "opening", "score_unit": "m", "nominal_floor": 0.05}, 0.05),
                                             ({"nominal_floor": None}, None), ({"nominal_floor": 0}, 0.0)])
def test_floor_defaults_when_absent_and_null_turns_it_off(task, floor):
    assert nominal_floor(task) == floor


@pytest.mark.parametrize("value", ["high", True, float("nan")])
def test_a_floor_that_is_not_a_number_is_refused(value):
    with pytest.raises(ScoreConfigError, match="task.nominal_floor"):
        nominal_floor({"nominal_floor": value})


def test_the_message_names_s0_the_floor_and_the_fix():
    spec = ScoreSpec(name="opening", unit="m", ci="bootstrap")
    check_nominal_floor(0.05, 0.05, spec)  # at the floor: goes on
    check_nominal_floor(0.0, None, spec)
    with pytest.raises(NominalFloorError) as err:
        check_nominal_floor(0.012, 0.05, spec)
    text = str(err.value)
    assert "\n" not in text
    assert "S0 = 0.012 m" in text and "task.nominal_floor = 0.05 m" in text
    assert "another object or policy" in text and "null" in text


@pytest.fixture(scope="module")
def stopped(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    run_dir = tmp_path_factory.mktemp("floor") / "run"
    res = grt_run("budget=smoke", "selector.k=3", "optimizer=gaussian", "task.nominal_floor=1.5", *TOY,
                  f"hydra.run.dir={run_dir}")
    return run_dir, res


def test_a_run_below_the_floor_stops_after_the_nominal_record(stopped):
    run_dir, res = stopped
    out = res.stdout + res.stderr
    assert res.returncode == 2, out
    assert "Traceback" not in out
    lines = [line for line in out.splitlines() if "nominal_floor" in line]
    assert len(lines) == 1, out
    assert "S0 = 1.00" in lines[0] and "task.nominal_floor = 1.50" in lines[0]
    assert f"python -m grt.run resume={run_dir} task.nominal_floor=0.75" in lines[0]
    records = journal(run_dir)
    assert [(r["iteration"], r["candidate"], r["score"]) for r in records] == [(0, 0, 1.0)]
    assert not (run_dir / "summary.json").exists()
    assert (run_dir / "nominal.obj").is_file()


def test_resume_with_a_lower_floor_reuses_the_nominal_and_keeps_the_topology(stopped, tmp_path):
    import shutil

    run_dir = tmp_path / "run"
    shutil.copytree(stopped[0], run_dir)
    res = grt_run(f"resume={run_dir}", "task.nominal_floor=null")
    assert res.returncode == 0, res.stdout + res.stderr
    summary = json.loads((run_dir / "summary.json").read_text())
    assert len(journal(run_dir)) == 1 + 3 * 2
    # the nominal record was not evaluated again (nor the implausible candidates, never simulated)
    assert summary["evaluated_this_session"] == sum(r["valid"] for r in journal(run_dir)[1:])

    nominal = trimesh.load(run_dir / "nominal.obj", process=False, force="mesh")
    mesh = load_mesh("mug", settings=MeshSettings(remesh="auto"))  # the task's default object, as the run loaded it
    np.testing.assert_allclose(nominal.vertices, mesh.vertices, atol=1e-12)
    np.testing.assert_array_equal(nominal.faces, mesh.faces)
    handles = HandleSet.from_json((run_dir / "handles.json").read_text())
    assert max(handles.handles.max(), handles.anchors.max()) < len(nominal.vertices)
    shapes = summary["crashshapes"] or summary["best_candidates"]  # (no failure: the best ones, in best/)
    assert shapes
    for entry in shapes:
        shape = trimesh.load(run_dir / entry["file"].replace(".stl", ".obj"), process=False, force="mesh")
        assert len(shape.vertices) == len(nominal.vertices)
        np.testing.assert_array_equal(shape.faces, nominal.faces)
        moved = np.linalg.norm(shape.vertices - nominal.vertices, axis=1)
        assert moved.max() > 0  # a deformation of the same vertices, not another mesh
