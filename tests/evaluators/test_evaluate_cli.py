"""The ``python -m grt.evaluate`` app: config composition, summary, errors (toy session, no simulator)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from omegaconf import OmegaConf

from grt.bench.grasp import compose


def test_evaluate_composes_and_scores_with_a_toy_session(toy_configs, u_mesh, tmp_path):
    from grt.evaluate import evaluate

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
    proc = subprocess.run([sys.executable, "-m", "grt.evaluate", f"object={obj}", f"hydra.run.dir={tmp_path}"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert message in proc.stderr
