"""rsl-rl's VecEnv adapter and PPO training on a tiny fake task (as rsl_rl tests its runner)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from grt.policies.rsl_rl import CheckpointError, RslRlPolicy
from grt.rl.train import TrainSpec, export_policy, train
from grt.rl.vec_env import TaskVecEnv
from grt.targets import ClassError


def test_vec_env_follows_the_rsl_rl_contract(reach_task, box_shape):
    env = TaskVecEnv(reach_task, [box_shape], num_envs=3, workers=0, seed=1)
    obs = env.get_observations()
    assert obs["state"].shape == (3, 2) and env.num_actions == 1 and env.obs_spec == {"state": (2,)}
    saw_timeout = False
    for _ in range(25):
        obs, rew, dones, extras = env.step(torch.zeros(3, 1))
        assert rew.shape == (3,) and dones.shape == (3,) and extras["time_outs"].shape == (3,)
        saw_timeout |= bool(extras["time_outs"].any())
    assert saw_timeout, "a zero action never reaches the goal: episodes must end by the time limit"
    assert all(not e["success"] and e["length"] == 20 for e in env.episodes)
    env.close()


def test_vec_env_is_reproducible_and_worker_count_free(reach_task, box_shape):
    def goals(workers):
        env = TaskVecEnv(reach_task, [box_shape], num_envs=2, workers=workers, seed=7)
        first = env.get_observations()["state"][:, 1].clone()
        env.close()
        return first

    assert torch.equal(goals(0), goals(0))
    assert torch.equal(goals(0), goals(2))  # one process or two: the same episodes


def test_a_session_that_cannot_be_built_is_one_line_with_its_traceback_in_a_file(reach_task, box_shape):
    """What grt.train says (exit code 2) when the task's session cannot be built (in this process; the workers
    send their traceback back and the same line is made of it: grt.targets.worker_error)."""
    task = {**reach_task, "session": {**reach_task["session"], "bogus_key": 1}}
    with pytest.raises(ClassError, match=r"task.session \(_reach_task.ReachSession\): building it raised TypeError: "
                                         r".*'bogus_key' \(the whole traceback: ") as info:
        TaskVecEnv(task, [box_shape], num_envs=1, workers=0, seed=0)
    assert len(str(info.value).splitlines()) == 1


def test_shape_weights_are_checked(reach_task, box_shape):
    with pytest.raises(ValueError, match="weights"):
        TaskVecEnv(reach_task, [box_shape], num_envs=1, workers=0, weights=[1.0, 2.0])


def test_ppo_learns_the_fake_task_and_the_checkpoint_loads(reach_task, box_shape, train_cfg, tmp_path):
    env = TaskVecEnv(reach_task, [box_shape], num_envs=8, workers=0, seed=0)
    result = train(env, TrainSpec(train_cfg, tmp_path, "reach", reach_task, iterations=40))
    env.close()
    rows = (tmp_path / "metrics.csv").read_text().splitlines()
    assert len(rows) == 41 and result["iterations"] == 40
    early = np.mean([e["success"] for e in env.episodes[:40]])
    late = np.mean([e["success"] for e in env.episodes[-40:]])
    assert late > max(0.8, early + 0.3), (early, late)
    small = export_policy(tmp_path / "last.pt", tmp_path / "policy.pt")
    policy = RslRlPolicy(str(small), task="reach")
    policy.check("reach", {"state": (2,)}, 1)
    act = policy.act({"state": np.array([[0.0, 0.5], [0.0, -0.5]], np.float32)})
    assert act.shape == (2, 1) and act[0, 0] > 0 > act[1, 0]  # it moves towards the goal
    with pytest.raises(CheckpointError, match="trained for task 'reach'.*'insertion'"):
        policy.check("insertion", {"state": (24,)}, 6)
    with pytest.raises(CheckpointError, match="expects observation 'state' of shape \\(2,\\)"):
        policy.check("reach", {"state": (3,)}, 1)
    with pytest.raises(CheckpointError, match=r"reads observation 'state' of shape \(2,\), which the task does not "
                                              r"give \(it gives rgb \(8, 8, 3\)\)"):  # it once said "gives None"
        policy.check("reach", {"rgb": (8, 8, 3)}, 1)
    with pytest.raises(CheckpointError, match="trained for task 'reach', not 'drawer'"):
        RslRlPolicy(str(small), task="drawer")


def test_training_resumes_from_its_last_checkpoint(reach_task, box_shape, train_cfg, tmp_path):
    env = TaskVecEnv(reach_task, [box_shape], num_envs=4, workers=0, seed=0)
    train(env, TrainSpec(train_cfg, tmp_path, "reach", reach_task, iterations=10, save_interval=5))
    first = torch.load(tmp_path / "last.pt", weights_only=False)
    result = train(env, TrainSpec(train_cfg, tmp_path, "reach", reach_task, iterations=15, save_interval=5))
    env.close()
    assert first["iter"] == 9 and result["iterations"] == 15
    assert len((tmp_path / "metrics.csv").read_text().splitlines()) == 16  # 15 rows, none repeated


@pytest.mark.parametrize("content", [b"", b"not a torch file"])
def test_bad_checkpoints_are_refused_with_the_fix(tmp_path, content):
    path = tmp_path / "x.pt"
    path.write_bytes(content)
    with pytest.raises(CheckpointError, match="cannot be read"):
        RslRlPolicy(str(path))
    with pytest.raises(CheckpointError, match="does not exist"):
        RslRlPolicy(str(tmp_path / "missing.pt"))
    torch.save({"actor_state_dict": {}}, path)
    with pytest.raises(CheckpointError, match="not a GRT rsl-rl checkpoint"):
        RslRlPolicy(str(path))


def test_a_frozen_normalizer_keeps_its_statistics_through_ppo(reach_task, box_shape, train_cfg, tmp_path):
    import torch

    env = TaskVecEnv(reach_task, [box_shape], num_envs=4, workers=0, seed=0)
    train(env, TrainSpec({**train_cfg, "freeze_normalization": True}, tmp_path, "reach", reach_task, iterations=3,
          save_interval=1))
    state = torch.load(tmp_path / "last.pt", map_location="cpu", weights_only=False)["actor_state_dict"]
    assert float(state["obs_normalizer.count"]) == 0.0  # no rollout updated it
    env2 = TaskVecEnv(reach_task, [box_shape], num_envs=4, workers=0, seed=0)
    train(env2, TrainSpec(train_cfg, tmp_path / "free", "reach", reach_task, iterations=3, save_interval=1))
    free = torch.load(tmp_path / "free" / "last.pt", map_location="cpu", weights_only=False)["actor_state_dict"]
    assert float(free["obs_normalizer.count"]) > 0.0


def test_a_success_bonus_is_paid_on_the_step_an_episode_succeeds_and_only_then(reach_task, box_shape):
    """A dense reward paid every step makes ending early a loss (PPO learned to hover by PushCube's goal); the
    bonus makes the success worth what it ends."""
    rewards = {}
    for bonus in (0.0, 10.0):
        env = TaskVecEnv(reach_task, [box_shape], num_envs=2, workers=0, seed=3, success_bonus=bonus)
        got = []
        for _ in range(30):
            goal = env.get_observations()["state"][:, 1:2]
            _, rew, dones, extras = env.step(torch.clamp(goal / 0.1, -1, 1))  # straight to the goal
            got.append((rew.clone(), (dones.bool() & ~extras["time_outs"].bool()).clone()))
        env.close()
        rewards[bonus] = got
    succeeded = torch.stack([d for _, d in rewards[0.0]])
    diff = torch.stack([r for r, _ in rewards[10.0]]) - torch.stack([r for r, _ in rewards[0.0]])
    assert succeeded.any() and torch.allclose(diff, 10.0 * succeeded.float())
