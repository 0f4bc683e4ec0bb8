"""The nominal anchor: a fine-tune pulled back to its starting policy's actions on that policy's states."""

from __future__ import annotations

import pytest

from grt.policies.rsl_rl import RslRlPolicy
from grt.rl.anchor import NominalAnchor
from grt.rl.train import TrainSpec, export_policy, train
from grt.rl.vec_env import TaskVecEnv


def test_an_anchored_fine_tune_stays_closer_to_the_policy_it_started_from(reach_task, box_shape, train_cfg, tmp_path):
    env = TaskVecEnv(reach_task, [box_shape], num_envs=4, workers=0, seed=0)
    train(env, TrainSpec(train_cfg, tmp_path / "start", "reach", reach_task, iterations=8))
    env.close()
    start = export_policy(tmp_path / "start" / "last.pt", tmp_path / "start.pt")
    reference = RslRlPolicy(str(start)).actor
    record_env = TaskVecEnv(reach_task, [box_shape], num_envs=4, workers=0, seed=3)
    anchor = NominalAnchor.record(reference, record_env, steps=20, noise=0.1, updates=16, lr=1e-3)
    record_env.close()
    assert len(anchor.targets) == 80 and anchor.error(reference) == pytest.approx(0.0, abs=1e-10)

    hot = {**train_cfg, "algorithm": {**train_cfg["algorithm"], "learning_rate": 1e-2}}  # a fine-tune that drifts
    drift = {}
    for name, use in (("free", None), ("anchored", anchor)):
        env = TaskVecEnv(reach_task, [box_shape], num_envs=4, workers=0, seed=5)
        train(env, TrainSpec(hot, tmp_path / name, "reach", reach_task, iterations=6, init_checkpoint=str(start), anchor=use))
        env.close()
        tuned = RslRlPolicy(str(export_policy(tmp_path / name / "last.pt", tmp_path / f"{name}.pt"))).actor
        drift[name] = anchor.error(tuned)
    assert drift["free"] > 0 and drift["anchored"] < 0.5 * drift["free"], drift
    rows = (tmp_path / "anchored" / "metrics.csv").read_text().splitlines()
    assert rows[0].endswith("anchor_mse") and all(float(r.split(",")[-1]) >= 0 for r in rows[1:])
    free_rows = (tmp_path / "free" / "metrics.csv").read_text().splitlines()
    assert free_rows[1].endswith("nan")  # no anchor: the column is empty, as in older runs resumed
    with pytest.raises(ValueError, match="anchor: updates=-1"):
        NominalAnchor(anchor.data, anchor.targets, updates=-1)
