"""The nominal guard as a class: validation rows, the start's episodes, and the refusal of a regression."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
import torch
import trimesh

from grt.blueteam.core import Geometry
from grt.blueteam.guard import GuardRule, NominalGuard


class _Evaluator:
    """Scores each geometry by a table keyed on the checkpoint being validated: ``{checkpoint: {name: [...]}}``."""

    def __init__(self, table: dict, shapes: list[Geometry]):
        self.table, self.names = table, {id(g.mesh): g.name for g in shapes}

    def evaluate(self, meshes, seeds, parts=None, policy=None):
        by_name = self.table[policy["checkpoint"]]
        names = [self.names[id(m)] for m in meshes]
        return [SimpleNamespace(sim_errors=0, trials=[SimpleNamespace(score=s, mode="success" if s else "timeout")
                                                      for s in by_name[n][:len(seeds)]]) for n in names]


def _shapes():
    box = trimesh.creation.box([0.01, 0.01, 0.01])
    return [Geometry(name, box.copy(), [], role) for name, role in (("nominal", "nominal"), ("it1_c0", "crashshape"))]


def test_a_checkpoint_that_loses_the_nominal_object_ranks_below_every_kept_one(tmp_path):
    shapes = _shapes()
    start, worse = tmp_path / "start.pt", tmp_path / "worse.pt"
    torch.save({"iter": -1}, start)
    torch.save({"iter": 9}, worse)
    ev = _Evaluator({str(start): {"nominal": [1.0] * 8, "it1_c0": [0.0, 0.0]},
                     str(worse): {"nominal": [0.0] * 8, "it1_c0": [1.0, 1.0]}}, shapes)
    guard = NominalGuard(tmp_path, {"checkpoint": "x"}, shapes, list(range(8)), ev, GuardRule(), crash_trials=2,
                         nominal_trials=8, keep=0)
    assert guard(start) == pytest.approx(0.0)  # the policy before fine-tuning: the guard's baseline
    saved = json.loads((tmp_path / "val_nominal.json").read_text())
    assert saved["scores"] == [1.0] * 8 and saved["guard"] == "fisher" and saved["binary"] is True
    assert guard(worse) == pytest.approx(1.0 - 2.0)  # best on the CrashShape, but refused: minus 2
    rows = [json.loads(line) for line in (tmp_path / "validation.jsonl").read_text().splitlines()]
    assert [(r["iteration"], r["regressed"]) for r in rows] == [(0, False), (10, True)]
