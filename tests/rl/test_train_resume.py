"""A killed training resumed from ``last.pt`` has the bookkeeping an uninterrupted one had at that iteration:
what the killed attempt did after it (validations, ``val_best.pt``, ``best.pt``, metrics rows) is dropped, in
one log line."""

from __future__ import annotations

import json
import logging

import pytest
import torch

from grt.rl.train import TrainSpec, ValidationSpec, train
from grt.rl.vec_env import TaskVecEnv


class Killed(Exception):
    """The training process killed (Ctrl-C, SIGTERM, a node lost)."""


def _scorer(scores: dict, kill_at: set | None = None):
    """``checkpoint -> score`` from ``scores[attempt][iteration]`` (the checkpoint's ``iter``); the attempt
    is ``scorer.attempt``; a validation at an iteration of ``kill_at`` (``(attempt, it)``) is killed."""

    def score(path):
        it = int(torch.load(path, map_location="cpu", weights_only=False)["iter"])
        if (score.attempt, it) in (kill_at or set()):
            raise Killed
        return scores[score.attempt][it]

    score.attempt = 0
    return score


def _kill_at(it: int):
    def on_iteration(row):
        if row["iteration"] == it:
            raise Killed

    return on_iteration


def _iter(path) -> int:
    return int(torch.load(path, map_location="cpu", weights_only=False)["iter"])


def _train(reach_task, box_shape, train_cfg, out, iterations, score, patience, **kw):
    env = TaskVecEnv(reach_task, [box_shape], num_envs=4, workers=0, seed=0)
    spec = TrainSpec(train_cfg, out, "reach", reach_task, iterations=iterations, save_interval=10, patience=3,
                     validation=ValidationSpec(score, interval=5, patience=patience, perfect=None), **kw)
    try:
        return train(env, spec)
    finally:
        env.close()


def test_a_resume_drops_what_the_killed_attempt_did_after_last_pt(reach_task, box_shape, train_cfg, tmp_path, caplog):
    score = _scorer({0: {-1: 0.1, 4: 0.2, 9: 0.3, 14: 0.9},
                     1: {14: 0.5, 19: 0.6, 24: 0.7, 29: 0.8}})
    with pytest.raises(Killed):  # validated after iteration 14, killed at 17: last.pt is iteration 9's
        _train(reach_task, box_shape, train_cfg, tmp_path, 30, score, 2, on_iteration=_kill_at(17))
    assert _iter(tmp_path / "last.pt") == 9 and _iter(tmp_path / "val_best.pt") == 14
    killed_best = _iter(tmp_path / "best.pt")

    score.attempt = 1
    with caplog.at_level(logging.INFO, logger="grt.rl.train"):  # the restart point, nothing trained
        _train(reach_task, box_shape, train_cfg, tmp_path, 10, score, 2)
    state = json.loads((tmp_path / "validation.json").read_text())
    assert state["history"] == [[-1, 0.1], [4, 0.2], [9, 0.3]] and state["stale"] == 0 and state["best"] == 0.3
    assert not (tmp_path / "val_best.pt").exists()  # iteration 14's replaced iteration 9's: nothing right is left
    assert (tmp_path / "best.pt").exists() == (killed_best <= 9)
    assert len((tmp_path / "metrics.csv").read_text().splitlines()) == 11
    dropped = [r.getMessage() for r in caplog.records if "dropped" in r.getMessage()]
    assert len(dropped) == 1 and "val_best.pt" in dropped[0] and "0.9" in dropped[0], dropped

    result = _train(reach_task, box_shape, train_cfg, tmp_path, 30, score, 2)
    state = json.loads((tmp_path / "validation.json").read_text())
    assert state["history"][3:] == [[14, 0.5], [19, 0.6], [24, 0.7], [29, 0.8]]  # no stop from 0.9 dropped
    assert not result["stopped_early"] and result["iterations"] == 30 and _iter(tmp_path / "val_best.pt") == 29
    best = torch.load(tmp_path / "best.pt", map_location="cpu", weights_only=False)
    assert best["grt"]["best_success"] == result["best_success"]


def test_a_resume_from_iteration_0_or_killed_in_a_validation_redoes_it(reach_task, box_shape, train_cfg, tmp_path):
    score = _scorer({0: {-1: 0.4, 4: 0.3}, 1: {-1: 0.4, 4: 0.3, 9: 0.2}, 2: {9: 0.2, 14: 0.35, 19: 0.5}},
                    kill_at={(1, 9)})
    with pytest.raises(Killed):  # killed before the first last.pt
        _train(reach_task, box_shape, train_cfg, tmp_path, 20, score, 3, on_iteration=_kill_at(7))
    assert not (tmp_path / "last.pt").exists()
    score.attempt = 1
    with pytest.raises(Killed):  # from iteration 0 again (no validation counted twice), killed validating 9
        _train(reach_task, box_shape, train_cfg, tmp_path, 20, score, 3)
    assert _iter(tmp_path / "last.pt") == 9
    assert json.loads((tmp_path / "validation.json").read_text())["history"] == [[-1, 0.4], [4, 0.3]]
    score.attempt = 2
    result = _train(reach_task, box_shape, train_cfg, tmp_path, 20, score, 3)
    state = json.loads((tmp_path / "validation.json").read_text())
    assert state["history"] == [[-1, 0.4], [4, 0.3], [9, 0.2], [14, 0.35]]  # 9 validated on resuming
    assert result["stopped_early"] and result["iterations"] == 15 and _iter(tmp_path / "val_best.pt") == -1
