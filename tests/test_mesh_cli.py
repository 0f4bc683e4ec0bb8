"""Every input case of issue 12 through the public CLIs: a reported, faithful repair (printed when the tool
starts, and in ``summary.json`` for ``grt.run``) or one ``error:`` line with exit code 2, no traceback.

``grt.run`` and ``grt.evaluate`` run without the simulator (the toy evaluator of the resume tests)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from grt.objects import get_object
from tests.geometry import _cases
from tests.runner._toy_run import TOY, ToyEvaluator

ROOT = Path(__file__).resolve().parents[1]
# grt.evaluate also reads the evaluator's collision time
TOY_EVALUATE = [TOY[0], "evaluator._target_=tests.test_mesh_cli.ToyEvaluateEvaluator"]


class ToyEvaluateEvaluator(ToyEvaluator):
    """The resume tests' toy evaluator, with the collision time ``grt.evaluate`` reports."""

    collision_s = 0.0


def cli(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "WANDB_MODE": "disabled"})


def _one_error_line(proc: subprocess.CompletedProcess) -> str:
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out
    assert "Traceback" not in out
    lines = [ln for ln in out.splitlines() if "error" in ln.lower()]
    assert len(lines) == 1, out
    return lines[0]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("inputs")
    meshes = {"can": _cases.open_can(), "spheres": _cases.two_spheres(), "coarse": _cases.coarse_cad()}
    paths = {}
    for name, mesh in meshes.items():
        paths[name] = folder / f"{name}.obj"
        mesh.export(paths[name])
    return paths


def test_run_prints_the_repair_and_stores_it_in_summary_json(inputs, tmp_path):
    proc = cli("grt.run", f"object={inputs['can']}", "budget=smoke", "selector.k=3", "optimizer=gaussian", *TOY,
               f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "watertight manifold conversion" in proc.stdout and "fidelity: volume ratio" in proc.stdout
    prep = json.loads((tmp_path / "summary.json").read_text())["mesh_preparation"]
    assert prep["source"] == str(inputs["can"]) and prep["remesh"]["done"]
    assert any("watertight manifold conversion" in r for r in prep["repairs"])
    assert prep["fidelity"]["hausdorff_mm"] <= prep["tolerance"]["fidelity_mm"]
    nominal = trimesh.load(tmp_path / "nominal.obj", process=False)
    assert len(nominal.faces) == prep["output"]["faces"]  # the prepared mesh is the one deformed


def test_run_refuses_two_bodies_in_one_line(inputs, tmp_path):
    line = _one_error_line(cli("grt.run", f"object={inputs['spheres']}", *TOY, f"hydra.run.dir={tmp_path}"))
    assert "2 separate closed bodies" in line and "mesh.components=largest" in line
    assert not (tmp_path / "journal.jsonl").exists()


def test_run_refuses_a_repair_beyond_the_tolerance(inputs, tmp_path):
    line = _one_error_line(cli("grt.run", f"object={inputs['can']}", "mesh.fidelity_mm=0.5", *TOY,
                               f"hydra.run.dir={tmp_path}"))
    assert "changed the object more than allowed" in line and "Fix:" in line


def test_evaluate_and_select_print_the_preparation(inputs, tmp_path):
    proc = cli("grt.evaluate", f"object={inputs['coarse']}", "budget=smoke", *TOY_EVALUATE,
               f"hydra.run.dir={tmp_path / 'e'}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "remeshed: coarse" in proc.stdout and "fidelity: volume ratio" in proc.stdout
    assert json.loads(proc.stdout.splitlines()[-1])["mesh_preparation"]["remesh"]["done"]
    proc = cli("grt.select", f"object={inputs['coarse']}", "selector.k=3", f"out_dir={tmp_path / 's'}")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "remeshed: coarse" in proc.stdout and "fidelity: volume ratio" in proc.stdout
    assert json.loads((tmp_path / "s" / "handles.json").read_text())["mesh_preparation"]["remesh"]["done"]


# ------------------------------------------------------------------ grt.deform: indices of the file
def _write(path: Path, idx, pos) -> Path:
    path.write_text("".join(f"{i} {x} {y} {z}\n" for i, (x, y, z) in zip(idx, pos, strict=True)))
    return path


def _can_with_a_stray_vertex(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray, np.ndarray]:
    """The can as an OBJ whose first vertex no face uses: every file index is the can's + 1."""
    can = get_object("can")
    v = np.asarray(can.vertices)
    lines = ["v 0.5 0.5 0.5"] + [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in v]
    lines += [f"f {a + 2} {b + 2} {c + 2}" for a, b, c in can.faces]
    path = tmp_path / "stray.obj"
    path.write_text("\n".join(lines) + "\n")
    h = np.argsort(-v[:, 2])[:2]
    a = np.flatnonzero(v[:, 2] < 0.005)
    return path, v, h, a


def test_deform_carries_file_indices_past_a_removed_vertex(tmp_path):
    path, v, h, a = _can_with_a_stray_vertex(tmp_path)
    hf = _write(tmp_path / "h.txt", h + 1, v[h] + [0, 0, 0.01])  # the file's own indices
    af = _write(tmp_path / "a.txt", a + 1, v[a])
    out = tmp_path / "out.obj"
    proc = cli("grt.deform", str(path), "--handles", str(hf), "--anchors", str(af), "--out", str(out), "--no-align")
    assert proc.returncode == 0, proc.stderr
    assert "read the file's 1323 vertices as 1322" in proc.stdout
    assert f"handles: {len(h)} of {len(h)} indices changed" in proc.stdout
    result = trimesh.load(out, process=False)
    np.testing.assert_allclose(result.vertices[h], v[h] + [0, 0, 0.01], atol=1e-6)  # the intended vertices moved


def test_deform_refuses_ambiguous_or_missing_indices(tmp_path):
    path, v, h, a = _can_with_a_stray_vertex(tmp_path)
    af = _write(tmp_path / "a.txt", a + 1, v[a])
    out = tmp_path / "out.obj"
    stray = _write(tmp_path / "h0.txt", [0], [[0.5, 0.5, 0.6]])  # the vertex that is gone
    line = _one_error_line(cli("grt.deform", str(path), "--handles", str(stray), "--anchors", str(af), "--out", str(out)))
    assert "handle 0" in line and "from every vertex of the prepared mesh" in line
    big = _write(tmp_path / "h9.txt", [10**6], [[0, 0, 0]])
    line = _one_error_line(cli("grt.deform", str(path), "--handles", str(big), "--anchors", str(af), "--out", str(out)))
    assert "out of range: the file has" in line
    assert not out.exists()


def test_deform_keeps_the_indices_of_an_unchanged_file(tmp_path):
    can = get_object("can")
    path = tmp_path / "can.obj"
    can.export(path)
    v = np.asarray(can.vertices)
    h, a = np.argsort(-v[:, 2])[:2], np.flatnonzero(v[:, 2] < 0.005)
    proc = cli("grt.deform", str(path), "--handles", str(_write(tmp_path / "h.txt", h, v[h] + [0, 0, 0.01])),
               "--anchors", str(_write(tmp_path / "a.txt", a, v[a])), "--out", str(tmp_path / "o.obj"))
    assert proc.returncode == 0, proc.stderr
    assert "carried" not in proc.stdout and "repaired:" not in proc.stdout
