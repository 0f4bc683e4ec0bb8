"""``python -m grt.select`` end to end, in a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]


def run_select(*overrides: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.select", *overrides], cwd=ROOT, text=True,
                          capture_output=True, timeout=120, env={**os.environ, **(env or {})})


def test_cli_heuristic(sphere, tmp_path):
    mesh_path = tmp_path / "ball.stl"
    sphere.export(mesh_path)
    out = tmp_path / "out"
    proc = run_select(f"object={mesh_path}", "selector=heuristic", "selector.k=6", f"out_dir={out}")
    assert proc.returncode == 0, proc.stderr
    assert "HeuristicSelector" in proc.stdout and "handles (6)" in proc.stdout
    record = json.loads((out / "handles.json").read_text())
    assert len(record["handles"]) == 6 and len(record["anchors"]) >= 3
    assert not set(record["handles"]) & set(record["anchors"])
    mesh = trimesh.load(mesh_path, process=True)
    # positions in meters: on the 4 cm sphere
    radii = np.linalg.norm(np.asarray(record["handle_positions"]), axis=1)
    np.testing.assert_allclose(radii, 0.04, rtol=1e-3)
    assert np.abs(mesh.vertices).max() < 0.05
    img = Image.open(out / "panel.png")
    assert img.size == (1024, 1024)


def test_cli_vlm_writes_no_key(chat_server, sphere, tmp_path):
    stage1 = json.dumps({"choices": [{"keypoint_indices": [0, 1], "semantic_object_label": "cap",
                                      "expected_transformations": ["flatten the top"]}]})
    stage2 = json.dumps({"top_choice": json.loads(stage1)["choices"][0]})
    server = chat_server([stage1, stage2])
    key = "sk-cli-SECRET-9876543210"
    mesh_path = tmp_path / "ball.stl"
    sphere.export(mesh_path)
    out = tmp_path / "out"
    proc = run_select(f"object={mesh_path}", "selector=vlm", f"selector.base_url={server.base_url}",
                      "selector.model=test-vlm", "selector.api_key_env=GRT_CLI_KEY",
                      f"selector.cache_dir={tmp_path / 'cache'}", "selector.num_samples=5000",
                      "selector.panel_px=256", f"out_dir={out}", env={"GRT_CLI_KEY": key})
    assert proc.returncode == 0, proc.stderr
    assert "cap" in proc.stdout and len(server.requests) == 2
    record = json.loads((out / "handles.json").read_text())
    assert record["expected_transformations"] == ["flatten the top"] and len(record["handles"]) == 2
    written = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert len(written) >= 5  # handles.json, panel.png, .hydra/*, two cache files
    for p in written:
        assert key.encode() not in p.read_bytes(), p


def test_every_selector_config_composes_and_instantiates(tmp_path):
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    import grt.config  # noqa: F401  (resolvers)
    from grt.selectors.base import HandleSelector

    names = sorted(p.stem for p in (ROOT / "conf" / "selector").glob("*.yaml"))
    assert names == ["all", "heuristic", "manual", "vlm"]
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        for name in names:
            cfg = compose("select", overrides=[f"selector={name}", f"out_dir={tmp_path}"],
                          return_hydra_config=False)
            selector = instantiate(cfg.selector)
            assert isinstance(selector, HandleSelector)
            assert type(selector).__module__ == f"grt.selectors.{name}"


def test_probe_counts_the_candidates_a_run_would_refuse_at_each_sigma(tmp_path):
    """``probe.sigmas``: a small σ leaves every first-iteration candidate valid, a huge one folds all."""
    out = tmp_path / "out"
    proc = run_select("object=can", "selector=heuristic", "probe.sigmas=[0.01,0.8]", "probe.candidates=4",
                      f"out_dir={out}")
    assert proc.returncode == 0, proc.stderr
    probe = json.loads((out / "probe.json").read_text())
    counts = {(r["search"], r["sigma"]): r["valid"] for r in probe["rows"]}
    assert counts == {("topdm", 0.01): 4, ("gaussian", 0.01): 4, ("topdm", 0.8): 0, ("gaussian", 0.8): 0}
    assert probe["deformer"]["method"] == "smooth" and probe["candidates"] == 4
    warning = next(line for line in proc.stdout.splitlines() if "fold the object" in line)
    assert "σ 0.8 over half" in warning and "0.01" not in warning


def test_probe_settings_are_checked_before_any_work(tmp_path):
    for override, message in (("probe.sigmas=0.03", "probe.sigmas must be a list"),
                              ("probe.sigmas=[0,1]", "probe.sigmas must be positive"),
                              ("probe.candidates=0", "probe.candidates must be a whole number")):
        proc = run_select("object=can", override, f"out_dir={tmp_path / 'out'}")
        assert proc.returncode == 2 and proc.stderr.strip().startswith("error: " + message), proc.stderr
        assert "Traceback" not in proc.stderr
    assert not (tmp_path / "out" / "handles.json").exists()


@pytest.mark.parametrize("flag", ["hydra.run.dir", "out_dir"])
def test_a_folder_another_process_holds_is_refused_and_left_as_it_was(flag, tmp_path):
    """Two ``grt.select`` in one folder would overwrite each other's ``handles.json``: the second is refused
    (the first's PID named) before it writes there, whichever of the two flags gives the folder."""
    from tests.cli._locked_folder import refused_while_locked

    folder = tmp_path / "select"
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "config.yaml").write_text("object: mug\n")
    (folder / "handles.json").write_text('{"handles": [1, 2], "anchors": [3, 4, 5]}')
    refused_while_locked("grt.select", folder, "object=can", "selector.k=3", f"{flag}={folder}")


def test_a_red_team_runs_folder_is_refused_without_touching_its_handles(tmp_path):
    """A red-team run keeps its ``handles.json`` (what its resume and its blue-team read): ``grt.select``
    given that folder is refused, saying so for grt.select, and changes nothing there."""
    from tests.cli._locked_folder import contents

    run = tmp_path / "run"
    (run / ".hydra").mkdir(parents=True)
    (run / "run_config.yaml").write_text("grt_format: 2\n")
    (run / "handles.json").write_text('{"handles": [1, 2], "anchors": [3, 4, 5]}')
    before = contents(run)
    proc = run_select("object=can", "selector.k=3", f"out_dir={run}")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.strip() == (f"error: hydra.run.dir={run} already holds a red-team run (run_config.yaml "
                                   "there), whose files python -m grt.select would overwrite or mix with its own: "
                                   "give it a folder of its own (hydra.run.dir=PATH, or leave it out for a new one)")
    assert contents(run) == before
