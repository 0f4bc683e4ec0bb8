"""ManiSkill PPO-baseline checkpoints (grt/policies/maniskill_ppo.py): the file ppo.py writes loads and acts
as ppo.py's actor does; a checkpoint for another env, or not ppo.py's Agent, is one line."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from grt.policies.maniskill_ppo import ManiSkillCheckpointError, ManiSkillPPOPolicy


def agent_state(obs: int, act: int, hidden: int = 256, seed: int = 0) -> dict:
    """The state dict of ppo.py's ``Agent`` (critic and actor_mean: Linear/Tanh x3 then Linear; actor_logstd)."""
    torch.manual_seed(seed)

    def mlp(out: int) -> nn.Sequential:
        return nn.Sequential(nn.Linear(obs, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
                             nn.Linear(hidden, hidden), nn.Tanh(), nn.Linear(hidden, out))

    agent = nn.Module()
    agent.critic, agent.actor_mean = mlp(1), mlp(act)
    agent.actor_logstd = nn.Parameter(torch.ones(1, act) * -0.5)
    return agent.state_dict(), agent


def test_a_ppo_py_checkpoint_acts_as_its_actor(tmp_path):
    state, agent = agent_state(obs=35, act=8)
    assert sorted(state)[:3] == ["actor_logstd", "actor_mean.0.bias", "actor_mean.0.weight"]
    torch.save(state, tmp_path / "final_ckpt.pt")
    policy = ManiSkillPPOPolicy(str(tmp_path / "final_ckpt.pt"))
    assert (policy.obs_size, policy.num_actions) == (35, 8)
    obs = np.random.default_rng(1).normal(size=(4, 35)).astype(np.float32) * 3
    with torch.no_grad():
        expect = agent.actor_mean(torch.as_tensor(obs)).clamp(-1, 1).numpy()
    np.testing.assert_allclose(policy.act({"state": obs}), expect, atol=1e-6)
    policy.check("pick_cube", {"state": (35,)}, 8)  # the env's sizes: accepted

    sampled = ManiSkillPPOPolicy(str(tmp_path / "final_ckpt.pt"), deterministic=False)
    sampled.reset(7)
    first = sampled.act({"state": obs})
    sampled.reset(7)
    np.testing.assert_array_equal(sampled.act({"state": obs}), first)  # a function of the episode seed
    assert np.abs(first - expect).max() > 0.05  # ... and not the mean


def test_sizes_that_do_not_fit_the_env_are_one_line_naming_both(tmp_path):
    torch.save(agent_state(obs=35, act=8)[0], tmp_path / "agent.pt")
    policy = ManiSkillPPOPolicy(str(tmp_path / "agent.pt"))
    with pytest.raises(ManiSkillCheckpointError) as err:
        policy.check("push_cube", {"state": (42,)}, 7)
    line = str(err.value)
    assert "\n" not in line and "35-D state" in line and "8 actions" in line and "42-D" in line and "7 actions" in line


def test_files_that_are_not_ppo_py_agents_are_refused(tmp_path):
    with pytest.raises(ManiSkillCheckpointError, match="does not exist"):
        ManiSkillPPOPolicy(str(tmp_path / "none.pt"))
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    with pytest.raises(ManiSkillCheckpointError, match="cannot be read"):
        ManiSkillPPOPolicy(str(tmp_path / "junk.pt"))
    torch.save({"grt": {}, "actor_state_dict": {}}, tmp_path / "grt.pt")
    with pytest.raises(ManiSkillCheckpointError, match="GRT checkpoint"):
        ManiSkillPPOPolicy(str(tmp_path / "grt.pt"))
    state = agent_state(obs=10, act=3, hidden=16)[0]
    state["actor_mean.2.weight"] = torch.zeros(16, 12)  # does not chain
    torch.save(state, tmp_path / "bad.pt")
    with pytest.raises(ManiSkillCheckpointError, match="does not take the previous layer's 16 outputs"):
        ManiSkillPPOPolicy(str(tmp_path / "bad.pt"))


class _Code:
    """Pickled code inside a checkpoint: never run by GRT."""


def _bad_checkpoints(tmp_path) -> dict[str, tuple[str, str]]:
    """Files a user may give as ``policy.checkpoint``, each with the words of its refusal."""
    import pickle

    out = {}
    (tmp_path / "run").mkdir()
    torch.save(agent_state(obs=35, act=8)[0], tmp_path / "run" / "final_ckpt.pt")
    out["folder"] = (str(tmp_path / "run"), "is a folder (final_ckpt.pt in it): give the .pt file")
    state = agent_state(obs=35, act=8)[0]
    torch.save({**state, "extra": _Code()}, tmp_path / "code.pt")
    out["code"] = (str(tmp_path / "code.pt"), "holds pickled Python code or objects (")
    (tmp_path / "plain.pkl").write_bytes(pickle.dumps({"actor_mean.0.weight": [[0.0]]}))
    out["pickle"] = (str(tmp_path / "plain.pkl"), "is a plain pickle, not a torch checkpoint")
    for name, key, value, words in (("int", "actor_mean.0.weight", torch.zeros(256, 35, dtype=torch.int64),
                                     "actor_mean.0.weight is torch.int64 (256, 35): a Linear layer's weight is a 2-D"),
                                    ("flat", "actor_mean.0.weight", torch.zeros(256 * 35),
                                     "actor_mean.0.weight is torch.float32 (8960,)"),
                                    ("bias", "actor_mean.0.bias", torch.zeros(7),
                                     "actor_mean.0.bias has 7 values, its weight (256, 35) 256 outputs")):
        torch.save({**state, key: value}, tmp_path / f"{name}.pt")
        out[name] = (str(tmp_path / f"{name}.pt"), words)
    return out


@pytest.mark.sim
def test_a_checkpoint_that_is_no_ppo_agent_is_one_line_through_the_command(tmp_path, capsys):
    """A folder was "does not exist", pickled code relayed PyTorch's advice to set weights_only=False, a weight
    of the wrong type or shape was cut to "Error(s) in loading state_dict for Linear:"."""
    from tests.cli._apps import app, error_line

    for name, (path, words) in _bad_checkpoints(tmp_path).items():
        code, _, err = app("evaluate", "task=push_cube", "policy=maniskill_ppo", f"policy.checkpoint={path}",
                           "budget.trials=1", f"hydra.run.dir={tmp_path / 'out'}", capsys=capsys)
        line = error_line(err)
        assert code == 2 and words in line and "weights_only" not in line, (name, line)
