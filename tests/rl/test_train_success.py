"""What ``grt.train`` says of a training's success (issue 40: a training shorter than ``train.patience`` printed
``best training success -1.00``, the sentinel the best starts from, while it had trained)."""

from __future__ import annotations

from grt.cli.train import training_success
from grt.rl.train import TrainSpec, train
from grt.rl.vec_env import TaskVecEnv


def test_a_training_shorter_than_its_patience_reports_its_last_success_not_a_sentinel(reach_task, box_shape,
                                                                                       train_cfg, tmp_path):
    env = TaskVecEnv(reach_task, [box_shape], num_envs=4, workers=0, seed=0)
    try:
        result = train(env, TrainSpec(train_cfg, tmp_path, "reach", reach_task, iterations=2, save_interval=10,
                                      patience=5))
    finally:
        env.close()
    assert result["best_success"] is None and not (tmp_path / "best.pt").exists()
    assert 0.0 <= result["last_success"] <= 1.0 and result["last_window"] == 2
    line = training_success(result, 5)
    assert "-1" not in line and f"training success {result['last_success']:.2f} over the last 2 iterations" in line
    assert "train.patience=5" in line
    assert training_success({"best_success": 0.75, "last_success": 0.5}, 30) == \
        "best training success 0.75 (over 30 iterations)"
    assert "no training episode ended" in training_success({"best_success": None, "last_success": None}, 30)
