"""A killed blue-team fine-tune resumed from ``last.pt`` has the guard's files an uninterrupted one had at that
iteration: the killed attempt's later ``validation.jsonl`` rows and ``candidates/`` are dropped (in the one log
line of :mod:`grt.rl.train`), so the confirmation chooses among checkpoints the resumed run has.

Driven on the tests' reach task (:mod:`tests.rl._reach_task`) with a scripted evaluator: seconds, no simulator.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import trimesh

from grt.blueteam.core import Geometry
from grt.cli.blueteam import study_spec
from grt.rl.train import TrainSpec, train
from grt.rl.vec_env import Shape, TaskVecEnv
from tests.rl.conftest import TRAIN_CFG
from tests.runner.conftest import compose_run

RL_TESTS = Path(__file__).resolve().parents[1] / "rl"


class Killed(Exception):
    """The fine-tune's process killed (Ctrl-C, SIGTERM, a node lost)."""


class _Evaluator:
    """Validation and confirmation episodes from a script: the starting policy succeeds on the nominal object
    (``start[attempt]`` of its episodes), a fine-tuned checkpoint on all of it and on ``crash[attempt][N]`` of
    each CrashShape's episodes, N its iteration (``iter + 1``); validating iteration ``kill[attempt]`` is killed."""

    def __init__(self, nominal, start_checkpoint: str, crash: dict, kill: dict, start: dict | None = None):
        self.nominal, self.start_checkpoint, self.crash, self.kill = nominal, start_checkpoint, crash, kill
        self.start, self.attempt = start, 0

    def evaluate(self, meshes, seeds, parts=None, policy=None):
        path, n = policy["checkpoint"], len(seeds)
        if path == self.start_checkpoint:
            ok = [(self.start or {}).get(self.attempt, n) if m is self.nominal else 0 for m in meshes]
        else:
            it = int(torch.load(path, map_location="cpu", weights_only=False)["iter"]) + 1
            if it == self.kill.get(self.attempt) and Path(path).name == "val_current.pt":
                raise Killed
            ok = [n if m is self.nominal else self.crash[self.attempt][it] for m in meshes]
        return [SimpleNamespace(sim_errors=0, trials=[SimpleNamespace(score=float(i < k), mode="success")
                                                      for i in range(n)]) for k in ok]

    def close(self):
        pass


@pytest.fixture
def study(tmp_path, monkeypatch):
    """``(run(attempt, iterations, patience), evaluator(...))``: a fine-tune of a one-iteration reach policy
    on the nominal box and one CrashShape, in ``tmp_path / "bt"``."""
    monkeypatch.syspath_prepend(str(RL_TESTS))
    task = {"name": "reach", "session": {"_target_": "_reach_task.ReachSession"}}
    box = trimesh.creation.box([0.06, 0.03, 0.05])
    shapes = [Geometry("nominal", box, [np.asarray(box.vertices)], "nominal"),
              Geometry("it1_c0", box.copy().apply_scale([0.5, 1, 1]), [np.asarray(box.vertices) * [0.5, 1, 1]],
                       "crashshape")]
    env = TaskVecEnv(task, [Shape.of(box, [np.asarray(box.vertices)], "box")], num_envs=2, workers=0, seed=0)
    try:
        train(env, TrainSpec(dict(TRAIN_CFG), tmp_path / "start", "reach", task, iterations=1))
    finally:
        env.close()
    start = str(tmp_path / "start" / "last.pt")
    ckpt = torch.load(start, map_location="cpu", weights_only=False)
    made = {}

    def make(crash: dict, kill: dict, start_nominal: dict | None = None) -> _Evaluator:
        made["ev"] = _Evaluator(shapes[0].mesh, start, crash, kill, start_nominal)
        return made["ev"]

    def run(attempt: int, iterations: int, patience: int) -> Path:
        from grt.blueteam.finetune import fine_tune

        made["ev"].attempt = attempt
        cfg = compose_run(["workers=0", "blueteam.nominal_share=0.5", "blueteam.num_envs=2", "blueteam.seed=0",
                           "blueteam.max_steps=10", "blueteam.anchor.updates=0", "blueteam.val_trials=16",
                           "blueteam.val_trials_nominal=4", "blueteam.confirm.candidates=2",
                           f"blueteam.iterations={iterations}", "blueteam.val_interval=1",
                           f"blueteam.val_patience={patience}", "blueteam.algorithm.learning_rate=1e-3",
                           "blueteam.num_steps_per_env=8", "blueteam.freeze_normalization=false",
                           "blueteam.nominal_guard=fisher", f"run={tmp_path / 'run'}"], config_name="blueteam")
        return fine_tune(study_spec(cfg), tmp_path / "bt", task, {"checkpoint": start}, ckpt, start, shapes,
                         list(range(16)), list(range(100, 116)), made["ev"])

    return run, make


def _rows(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "validation.jsonl").read_text().splitlines()]


def test_a_resume_drops_the_killed_attempts_later_validations_and_candidates(study, tmp_path, caplog):
    run, make = study
    out = tmp_path / "bt"
    # iteration N's CrashShape successes (of 16): attempt 0 gains every validation, killed validating 9 (last.pt
    # is iteration 5's: saved every 5); attempt 1, resumed at 5, gains nothing and stops at 7 (patience 2)
    ev = make({0: {n: n for n in range(12)}, 1: {**{n: n for n in range(12)}, 6: 2, 7: 2}}, kill={0: 9})
    with pytest.raises(Killed):
        run(0, 12, 2)
    assert [r["iteration"] for r in _rows(out)] == list(range(9))
    assert sorted(p.name for p in (out / "candidates").iterdir()) == ["it7.pt", "it8.pt"]

    ev.attempt = 1
    with caplog.at_level(logging.INFO):
        policy = run(1, 12, 2)
    assert [r["iteration"] for r in _rows(out)] == list(range(8))  # 0-5 of the killed attempt, 6-7 resumed
    assert [r["crashshapes"]["it1_c0"] for r in _rows(out)][6:] == [2 / 16, 2 / 16]
    confirm = json.loads((out / "confirm.json").read_text())
    # iteration 8 (8/16 on validation) was the killed attempt's: the resumed run never had it; iteration 5's
    # checkpoint is last.pt's, kept again; 4's was gone before the kill (displaced by 7 and 8)
    assert [c["iteration"] for c in confirm["candidates"]] == [5] and confirm["chosen"] == 5
    assert torch.load(policy, map_location="cpu", weights_only=False)["iter"] + 1 == 5
    assert sorted(p.name for p in (out / "candidates").iterdir()) == ["it5.pt"]
    dropped = [r.getMessage() for r in caplog.records if "dropped" in r.getMessage()]
    assert len(dropped) == 1, dropped
    assert "3 rows of validation.jsonl (iterations 6, 7, 8)" in dropped[0], dropped
    assert "candidates/it7.pt" in dropped[0] and "candidates/it8.pt" in dropped[0], dropped


def test_a_restart_from_iteration_0_validates_the_untrained_policy_once(study, tmp_path, caplog):
    run, make = study
    out = tmp_path / "bt"
    # killed validating 3, before the first last.pt: the resume starts again at 0; the start's nominal
    # episodes of the two attempts differ (a simulator that is not bit for bit repeatable)
    ev = make({0: {n: n for n in range(5)}, 1: {n: n for n in range(5)}}, kill={0: 3}, start_nominal={0: 3, 1: 4})
    with pytest.raises(Killed):
        run(0, 4, 3)
    assert not (out / "last.pt").exists() and [r["iteration"] for r in _rows(out)] == [0, 1, 2]
    ev.attempt = 1
    with caplog.at_level(logging.INFO):
        run(1, 4, 3)
    rows = _rows(out)
    assert [r["iteration"] for r in rows] == [0, 1, 2, 3, 4]
    start = json.loads((out / "val_nominal.json").read_text())  # the guard's baseline is the resumed run's
    assert start["scores"] == rows[0]["episodes"]["nominal"] == [1.0] * 4
    dropped = [r.getMessage() for r in caplog.records if "dropped" in r.getMessage()]
    assert len(dropped) == 1 and "3 rows of validation.jsonl (iterations 0, 1, 2)" in dropped[0], dropped
