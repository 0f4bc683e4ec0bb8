"""A run's folder names what was red-teamed, and a millimetre input gets its CrashShapes in millimetres too
(issue 40, "What stopped or misled the new user").

Antipodal, Contact-GraspNet and a user's policy used to land in one ``outputs/grasp/can/heuristic-topdm/``,
and a user's ``can.obj`` beside the built-in can's runs: the policy and the mesh file's name are in the path
now (``conf/hydra/default.yaml``). The CrashShapes of ``object_scale=0.001`` were written in meters only, which
a slicer reads as 0.066 mm across. Folders of the layout before still resume (``resume=`` continues a run in
its own folder: ``tests/runner/test_runfolder.py``) and ``grt.report`` reads sweeps of both layouts.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig

from grt.objects import get_object
from grt.report.tables import collect
from tests.runner._toy_run import TOY
from tests.runner.conftest import CONF

ROOT = Path(__file__).resolve().parents[2]


def _grt(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
           "WANDB_MODE": "disabled"}
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True, timeout=300,
                          env=env)


def test_a_users_millimetre_can_gets_its_own_folder_named_with_the_policy_and_files_in_mm(toy_run, tmp_path):
    mesh = tmp_path / "meshes" / "can.obj"  # the user's can, named like the built-in one, in millimetres
    mesh.parent.mkdir()
    can = get_object("can")
    can.apply_scale(1000.0)
    can.export(mesh)
    old = tmp_path / "outputs" / "grasp" / "can" / "heuristic-topdm" / "2026-01-01_00-00-00"  # the layout before
    shutil.copytree(toy_run, old)

    res = _grt("grt.run", f"object={mesh}", "object_scale=0.001", "budget=smoke", "selector.k=3", "budget.trials=2",
               "budget.sigma=0.06", "+evaluator.bar_mm=4", *TOY, cwd=tmp_path)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    (run,) = (tmp_path / "outputs" / "grasp" / "can.obj" / "antipodal" / "heuristic-topdm").iterdir()
    assert sorted(p.name for p in (tmp_path / "outputs" / "grasp").iterdir()) == ["can", "can.obj"]

    summary = json.loads((run / "summary.json").read_text())
    shapes = summary["crashshapes"] or summary["best_candidates"]
    assert shapes and all(e["input_unit"] == "mm" for e in shapes)
    for e in shapes:
        meters = trimesh.load(run / e["file"], process=False)
        mm = trimesh.load(run / e["file_input_units"], process=False)
        assert e["file_input_units"].endswith("_mm.stl")
        assert 0.06 < meters.extents[0] < 0.075 and 60 < mm.extents[0] < 75  # the can is 66 mm across
        np.testing.assert_allclose(mm.vertices, meters.vertices * 1000.0, rtol=1e-5)
    readme = (run / Path(shapes[0]["file"]).parent / "README.txt").read_text()
    assert "METERS" in readme and "_mm.stl" in readme and "object_scale=0.001" in readme
    assert "in the input's units too: rank*_mm.stl" in res.stdout

    rows = collect(tmp_path / "outputs")[0]  # what python -m grt.report reads: runs of both layouts
    assert sorted(Path(r["run"]) for r in rows) == sorted([old, run])


def test_a_sweeps_job_folders_name_the_policy():
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose("run", overrides=["task=insertion", "policy=insertion_pcd"], return_hydra_config=True)
    cfg.hydra.job.num = 3
    HydraConfig.instance().set_config(cfg)
    assert cfg.hydra.sweep.subdir == "3_insertion_pcd_heuristic-topdm"
    assert Path(cfg.hydra.run.dir).parent.parent.parts[-3:] == ("insertion", "usb_plug", "insertion_pcd")
