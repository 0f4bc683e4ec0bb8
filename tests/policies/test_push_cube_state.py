"""The shipped PPO policy for ManiSkill's stock PushCube-v1 (conf/policy/push_cube_state.yaml, trained by
``python -m grt.train task=push_cube train=push_cube_state``): it carries its config, pushes the stock cube
to the goal, and written as ManiSkill's ppo.py checkpoint (``ppo_agent_state``) it acts the same through
``policy=maniskill_ppo``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from grt.config import plain
from grt.evaluators.pool import build_session
from grt.policies.maniskill_ppo import ManiSkillPPOPolicy, ppo_agent_state, read_agent
from grt.policies.rsl_rl import RslRlPolicy, load_checkpoint
from tests.runner.conftest import compose_run

SEEDS = [1, 2]  # episode seeds, as a red-team run draws them


@pytest.mark.sim
def test_the_shipped_policy_pushes_the_cube_and_its_ppo_py_form_acts_the_same(tmp_path):
    cfg = compose_run(["task=push_cube", "policy=push_cube_state"], config_name="evaluate")
    task, policy = plain(cfg.task), plain(cfg.policy)
    path = policy["checkpoint"]
    grt = load_checkpoint(path)["grt"]
    assert grt["task"] == "push_cube" and grt["obs_spec"] == {"state": [35]} and grt["num_actions"] == 4
    assert {"train_cfg", "task_cfg", "metrics"} <= set(grt) and grt["metrics"]["evaluation"]["trials"] == 64
    session = build_session(task, policy)
    try:
        session.load_object(None, None)  # the stock cube
        trained = [session.run_trial(s) for s in SEEDS]
        assert [t.mode for t in trained] == ["success", "success"], [t.info for t in trained]

        torch.save(ppo_agent_state(path), tmp_path / "agent.pt")  # ppo.py's Agent.state_dict(), as it saves it
        assert {"actor_mean.6.weight", "critic.6.bias", "actor_logstd"} <= set(read_agent(tmp_path / "agent.pt"))
        agent = ManiSkillPPOPolicy(str(tmp_path / "agent.pt"))
        obs = {k: v[None] for k, v in session.reset(SEEDS[0]).items()}
        np.testing.assert_allclose(agent.act(obs), RslRlPolicy(path, task="push_cube").act(obs), atol=1e-4)
        session.set_policy(agent)  # checked against the env's sizes
        assert [session.run_trial(s).mode for s in SEEDS] == ["success", "success"]
    finally:
        session.close()
