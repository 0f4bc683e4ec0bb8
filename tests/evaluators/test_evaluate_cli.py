"""The ``python -m grt.evaluate`` app: config composition, summary, errors (toy session, no simulator)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from omegaconf import OmegaConf, open_dict

from grt.bench.grasp import compose


def test_evaluate_composes_and_scores_with_a_toy_session(toy_configs, u_mesh, tmp_path):
    from grt.cli.evaluate import evaluate

    path = tmp_path / "u_block.ply"
    u_mesh.export(path)
    cfg = compose([f"object={path}", "budget=smoke", "budget.trials=4", "evaluator.workers=1",
                   "evaluator.progress=false", f"evaluator.cache_dir={tmp_path / 'coacd'}"])
    assert cfg.evaluator._target_ == "grt.evaluators.sim.SimEvaluator"
    task, policy = toy_configs()
    cfg.task.session = OmegaConf.create(task["session"])
    cfg.policy = OmegaConf.create(policy)
    summary = evaluate(cfg, tmp_path / "out")
    assert summary["trials"] == 4 and sum(summary["outcomes"].values()) == 4
    assert 0.0 <= summary["ci95"][0] <= summary["success_rate"] <= summary["ci95"][1] <= 1.0
    record = json.loads((tmp_path / "out" / "evaluation.json").read_text())
    assert len(record["trials"]) == 4 and record["seeds"] == [t["seed"] for t in record["trials"]]
    json.dumps(summary)  # the printed last line must be valid JSON


@pytest.mark.parametrize(("obj", "message"), [("no_such_object", "unknown object 'no_such_object'"),
                                               ("corrupt.obj", "contains no triangles")])
def test_clear_errors_for_bad_objects(obj, message, tmp_path):
    if obj.endswith(".obj"):
        (tmp_path / obj).write_text("this is not a mesh\n")
        obj = str(tmp_path / obj)
    proc = subprocess.run([sys.executable, "-m", "grt.evaluate", f"object={obj}", f"hydra.run.dir={tmp_path / 'out'}"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert message in proc.stderr


def test_evaluate_reports_a_continuous_score_with_its_unit_and_interval(toy_configs, u_mesh, tmp_path):
    from grt import metrics
    from grt.cli.evaluate import evaluate, figures

    path = tmp_path / "u_block.ply"
    u_mesh.export(path)
    cfg = compose([f"object={path}", "budget=smoke", "budget.trials=6", "evaluator.workers=1",
                   "evaluator.progress=false", f"evaluator.cache_dir={tmp_path / 'coacd'}"])
    task, policy = toy_configs(continuous=True)
    with open_dict(cfg):
        cfg.task.session = OmegaConf.create(task["session"])
        cfg.task.score, cfg.task.score_unit, cfg.task.ci = "height", "m", "bootstrap"
    cfg.policy = OmegaConf.create(policy)
    summary = evaluate(cfg, tmp_path / "out")
    heights = [t["score"] for t in json.loads((tmp_path / "out" / "evaluation.json").read_text())["trials"]]
    assert 0.0 < summary["score"] < 0.05 and not set(heights) <= {0.0, 1.0}  # meters, not a success rate
    assert summary["ci95"] == list(metrics.bootstrap_interval(heights))
    assert (summary["score_name"], summary["score_unit"], summary["ci"]) == ("height", "m", "bootstrap")
    text = figures(summary)
    assert f"mean height (m) {summary['score']:.4g} m  95% CI [" in text and "(bootstrap)" in text
    assert "success rate" in text  # still shown, on its own line
    assert json.loads(json.dumps(summary))["score"] == summary["score"]


def test_figures_of_a_binary_task_say_success_rate():
    from grt.cli.evaluate import figures

    summary = {"object": "mug", "mesh_hash": "abc", "score": 0.75, "success_rate": 0.75, "ci95": [0.3, 0.95],
               "trials": 4, "outcomes": {"success": 3, "missed": 1}, "wall_s": 1.0, "trials_per_s": 4.0,
               "worker_s": 1.0, "collision_s": 0.01}  # written before score_name existed: a success rate
    assert "success rate  0.750  95% CI [0.300, 0.950] (auto)  over 4 trials" in figures(summary)


def test_a_crashshape_file_is_scored_with_the_parts_its_run_saved(toy_configs, u_mesh, tmp_path):
    """A run saves each CrashShape with its simulated convex parts; re-scoring the file uses them."""
    import trimesh

    from grt.cli.evaluate import evaluate, saved_parts
    from grt.evaluators.collision import CollisionError

    path = tmp_path / "rank1_it2_c5.obj"
    u_mesh.export(path)
    folder = tmp_path / "rank1_it2_c5_parts"
    folder.mkdir()
    halves = [u_mesh.vertices[u_mesh.vertices[:, 0] <= 0], u_mesh.vertices[u_mesh.vertices[:, 0] >= 0]]
    for i, verts in enumerate(halves):
        trimesh.convex.convex_hull(verts).export(folder / f"part{i:02d}.obj")
    parts, where = saved_parts(str(path), "auto")
    assert where == folder and len(parts) == 2
    assert saved_parts(str(path), "decompose") == (None, None)
    assert saved_parts("usb_plug", "auto") == (None, None)  # a built-in object has no saved parts
    with pytest.raises(CollisionError, match="parts='cached' is not a setting"):
        saved_parts(str(path), "cached")

    cfg = compose([f"object={path}", "budget=smoke", "budget.trials=2", "evaluator.workers=1",
                   "evaluator.progress=false", f"evaluator.cache_dir={tmp_path / 'coacd'}"])
    task, policy = toy_configs()
    cfg.task.session = OmegaConf.create(task["session"])
    cfg.policy = OmegaConf.create(policy)
    assert evaluate(cfg, tmp_path / "out")["collision_parts"] == str(folder)

    for f in folder.iterdir():
        f.unlink()
    with pytest.raises(CollisionError, match="no usable convex parts"):
        saved_parts(str(path), "auto")


def test_a_folder_another_process_holds_is_refused_and_left_as_it_was(tmp_path):
    """Two ``grt.evaluate`` in one folder would write over each other's ``evaluation.json``: the second is
    refused (the first's PID named) before any simulation, and writes nothing there."""
    from tests.cli._locked_folder import refused_while_locked

    folder = tmp_path / "evaluate"
    (folder / ".hydra").mkdir(parents=True)
    (folder / ".hydra" / "config.yaml").write_text("object: can\n")
    (folder / "evaluation.json").write_text('{"score": 0.5, "trials": []}')
    refused_while_locked("grt.evaluate", folder, "object=can", "budget.trials=1", f"hydra.run.dir={folder}")
