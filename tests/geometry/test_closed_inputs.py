"""Closed inputs are kept closed (issue 33 §1, issue 30 items 10-11): zero-area faces along seams are
collapsed in place, never deleted (which opened the mesh and had it rebuilt 10 mm away); figures are
measured against the input as given (exact volume when it is closed, else marked as an estimate); a
refusal names the step that changed the object and a fix that works."""

from __future__ import annotations

import re

import pytest
import trimesh

from grt.geometry.mesh import load_mesh, prepare_mesh
from grt.geometry.prepare import MeshSettings, describe
from grt.geometry.validation import MeshError
from tests.geometry import _cases

AUTO = MeshSettings(remesh="auto")


def _prep(mesh):
    return mesh.metadata["grt_prepare"]


@pytest.mark.parametrize("remesh", ["off", "auto"])
def test_a_closed_carton_with_zero_area_seam_faces_stays_closed_and_exact(tmp_path, remesh):
    carton = _cases.carton(caps=7)
    assert carton.is_watertight and (~carton.nondegenerate_faces(height=1e-12)).sum() == 7
    path = tmp_path / "carton.obj"
    carton.export(path)
    mesh = load_mesh(path, settings=MeshSettings(remesh=remesh))
    prep = _prep(mesh)
    assert any(r.startswith("collapsed 7 of 7 zero-area faces") and "did not move" in r for r in prep["repairs"])
    assert not any("watertight manifold conversion" in r or "removed" in r for r in prep["repairs"])
    assert mesh.volume == pytest.approx(carton.volume, rel=1e-6)  # exactly the carton, not a rebuilt one
    assert prep["fidelity"]["hausdorff_mm"] < 0.05 and not prep["fidelity"]["volume_estimated"]
    assert prep["exact"] == (remesh == "off")


def test_slivers_and_seam_faces_of_a_cad_part_are_remeshed_against_its_exact_volume():
    part = _cases.with_seam_caps(_cases.coarse_cad(), caps=4)  # fans of long thin triangles, and caps
    mesh = prepare_mesh(part, settings=AUTO)
    prep = _prep(mesh)
    assert any(r.startswith("collapsed") for r in prep["repairs"]) and prep["remesh"]["done"]
    assert abs(prep["fidelity"]["volume_ratio"] - 1) < 0.002 and prep["fidelity"]["hausdorff_mm"] < 0.5
    assert not prep["fidelity"]["volume_estimated"] and mesh.nondegenerate_faces(height=1e-12).all()


def test_an_open_input_says_its_volume_is_an_estimate():
    mesh = prepare_mesh(_cases.open_can(), settings=AUTO)
    prep = _prep(mesh)
    assert prep["fidelity"]["volume_estimated"]
    assert any("input volume estimated" in line for line in describe(mesh))


def test_a_refusal_of_grts_own_remeshing_names_it_and_its_fixes_work():
    part = _cases.with_seam_caps(_cases.coarse_cad(), caps=2)
    with pytest.raises(MeshError) as err:
        prepare_mesh(part, settings=MeshSettings(remesh="auto", fidelity_mm=0.001))
    text = str(err.value)
    assert text.startswith("GRT's own remeshing step changed the object") and "your mesh is closed" in text
    assert "modelling tool" not in text and "\n" not in text
    assert "mesh.remesh=off" in text
    kept = prepare_mesh(part, settings=MeshSettings(remesh="off", fidelity_mm=0.001))  # fix 1: works, exactly
    assert _prep(kept)["fidelity"]["hausdorff_mm"] < 1e-6
    accept = re.search(r"mesh\.fidelity_mm=([0-9.e-]+)", text.split("Fix:")[1]).group(1)
    prepare_mesh(part, settings=MeshSettings(remesh="auto", fidelity_mm=float(accept)))  # fix 2: works


def test_a_refusal_after_closing_an_open_input_names_the_opening_and_its_fix_works():
    can = _cases.open_can()  # three open sheets: closed by GRT's watertight conversion
    with pytest.raises(MeshError, match=r"^the input is not one closed solid \(.*not watertight.*closing it changed"
                       ) as err:
        prepare_mesh(can, settings=MeshSettings(remesh="auto", fidelity_mm=0.5))
    accept = re.search(r"mesh\.fidelity_mm=([0-9.e-]+)", str(err.value).split("Fix:")[1]).group(1)
    prepare_mesh(can, settings=MeshSettings(remesh="auto", fidelity_mm=float(accept)))
    cup = trimesh.creation.cylinder(0.03, 0.08, sections=48)
    cup.update_faces(cup.face_normals[:, 2] < 0.5)  # no top: closed into a thin shell around the sheet
    with pytest.raises(MeshError, match="could not close it into a solid") as err:
        prepare_mesh(cup, settings=AUTO)
    assert "volume_tol" not in str(err.value).split("Fix:")[1]  # accepting a shell is no fix


def test_a_single_flat_triangle_is_refused_for_having_no_volume(tmp_path):
    path = tmp_path / "tri.obj"
    trimesh.Trimesh([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], [[0, 1, 2]], process=False).export(path)
    with pytest.raises(MeshError, match=r"has no volume: all its 3 vertices \(1 faces\) lie in one plane") as err:
        load_mesh(path, settings=AUTO)
    assert "nan" not in str(err.value)


@pytest.mark.slow
def test_a_fine_closed_uv_sphere_is_decimated_keeping_its_volume():
    # one aggressive quadric decimation of this 539k-face sphere to 12k faces kept 0.54 of its volume (a
    # 1.5M-face one: 0.56, and the run was refused blaming the user's mesh); ~10 s
    sphere = _cases.uv_sphere()
    mesh = prepare_mesh(sphere, settings=AUTO)
    prep = _prep(mesh)
    decimated = next(r for r in prep["repairs"] if r.startswith("decimated"))
    assert "halving stages" in decimated and "stopped early" in decimated
    assert abs(prep["fidelity"]["volume_ratio"] - 1) < 0.01 and prep["fidelity"]["hausdorff_mm"] < 1.0
    assert not prep["fidelity"]["volume_estimated"]
