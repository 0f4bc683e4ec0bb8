"""``python -m grt.bench meshes``: the inputs table and the CrashShape measurements, through the CLI.

The demo measurement reads a run folder; here one is written by the deformer itself (no simulation): a
point-handle shape (a spike) and a smooth one, so the bench's spike figure must tell them apart.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import load_mesh
from grt.geometry.prepare import MeshSettings
from grt.selectors.heuristic import HeuristicSelector

ROOT = Path(__file__).resolve().parents[1]


def _run_folder(path: Path, method: str) -> Path:
    mesh = load_mesh("bottle", settings=MeshSettings(remesh="auto"))
    hs = HeuristicSelector(k=6, seed=0).select(mesh, "")
    theta = 0.03 * np.random.default_rng(0).standard_normal((len(hs.handles), 3))
    shape = ShapeDeformer(mesh, hs.handles, hs.anchors, method=method).meshes(theta[None])[0]
    (path / "crashshapes").mkdir(parents=True)
    mesh.export(path / "nominal.obj")
    shape.export(path / "crashshapes" / "rank0.obj")
    (path / "handles.json").write_text(hs.to_json(mesh))
    (path / "summary.json").write_text(json.dumps({
        "crashshapes": [{"rank": 0, "file": "crashshapes/rank0.stl", "score": 0.0}], "deformer": {"method": method},
        "final_drop": 1.0, "iter_at_50": 1, "delta_complexity": 0.05, "invalid_candidates": 0, "wall_s": 1.0}))
    return path


def _bench(*args: str) -> dict:
    proc = subprocess.run([sys.executable, "-m", "grt.bench", "meshes", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "toy_cylinder" in proc.stdout and "demo CrashShapes" in proc.stdout
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_meshes_bench_measures_inputs_and_tells_a_spike_from_a_bump(tmp_path):
    smooth = _bench("--objects", "tests/data/real/toy_cylinder.obj", "--skip-300k",
                    "--run", str(_run_folder(tmp_path / "smooth", "smooth")))
    assert {"spike_ratio_max", "delta_complexity", "final_drop", "self_intersecting"} <= set(smooth)
    row = smooth["objects"][0]
    assert row["prepared_faces"] > row["input_faces"]  # the coarse CAD cylinder is remeshed
    assert row["smooth_spike"] <= 1.3 < row["exact_spike"]
    assert smooth["spike_ratio_max"] <= 1.3 and smooth["self_intersecting"] == 0
    point = _bench("--objects", "tests/data/real/toy_cylinder.obj", "--skip-300k",
                   "--run", str(_run_folder(tmp_path / "exact", "exact")))
    assert point["spike_ratio_max"] > 1.3
