"""Checkpoints of ManiSkill's PPO baseline, as ManiSkill users have them (``policy.checkpoint=agent.pt``).

ManiSkill's ``examples/baselines/ppo/ppo.py`` (and ``ppo_fast.py``) save ``Agent.state_dict()`` with
``torch.save``: a plain dict of tensors, no config. The actor is an MLP on the flattened state observation
(``obs_mode="state"``)::

    actor_mean.0.weight  (H, D)    actor_mean.0.bias  (H,)     Linear, then Tanh
    actor_mean.2.weight  (H, H)    ...                         Linear, then Tanh
    actor_mean.4.weight  (H, H)    ...                         Linear, then Tanh
    actor_mean.6.weight  (A, H)    actor_mean.6.bias  (A,)     Linear: the action mean
    actor_logstd         (1, A)                                log standard deviation
    critic.0.weight ...                                        the value network (unused here)

(``H`` = 256 in ppo.py; the layer count and widths are read from the file). The policy acts with the mean
(as ppo.py evaluates, ``deterministic=True``) or samples with ``exp(actor_logstd)``, seeded per episode,
and clips to [-1, 1] (the normalized action space of ManiSkill's ``pd_*`` controllers). ppo.py trains with
``control_mode=pd_joint_delta_pos`` unless told otherwise: the task YAML must use the control mode the
checkpoint was trained with; the observation and action sizes are checked against the env.
"""

from __future__ import annotations

import pickle
import re
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import nn

from grt.errors import UserError
from grt.policies.base import BatchedPolicy

_LINEAR = re.compile(r"actor_mean\.(\d+)\.(weight|bias)")
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


class ManiSkillCheckpointError(UserError):
    """A ManiSkill PPO checkpoint that is missing, unreadable, not ppo.py's ``Agent``, or for another env."""


def read_agent(path: str | Path) -> dict[str, torch.Tensor]:
    """The state dict of a ppo.py checkpoint (CPU tensors, loaded with ``weights_only``: no code runs).

    Raises:
        ManiSkillCheckpointError: missing or unreadable file, or no ``actor_mean`` MLP inside.
    """
    path = Path(path).expanduser()
    if path.is_dir():
        inside = ", ".join(p.name for p in sorted(path.glob("*.pt"))[:3]) or "no .pt file"
        raise ManiSkillCheckpointError(f"policy.checkpoint={path} is a folder ({inside} in it): give the .pt file "
                                       "ManiSkill's ppo.py saved (runs/<run>/final_ckpt.pt or ckpt_<N>.pt)")
    if not path.is_file():
        raise ManiSkillCheckpointError(f"policy.checkpoint={path} does not exist: give the .pt file ManiSkill's "
                                       "ppo.py saved (runs/<run>/final_ckpt.pt or ckpt_<N>.pt)")
    try:
        with warnings.catch_warnings():  # a plain pickle: torch warns of its protocol before refusing it
            warnings.simplefilter("ignore")
            state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as err:
        raise ManiSkillCheckpointError(_unreadable(path, str(err))) from None
    except Exception as err:
        raise ManiSkillCheckpointError(f"policy.checkpoint={path} cannot be read as a torch state dict "
                                       f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''})") from err
    if not isinstance(state, dict) or not any(_LINEAR.fullmatch(k) for k in state):
        what = "a GRT checkpoint: use its own policy config (grt.policies.rsl_rl)" if isinstance(state, dict) and \
            "grt" in state else "no actor_mean.<i>.weight inside"
        raise ManiSkillCheckpointError(f"policy.checkpoint={path} is not a ManiSkill PPO Agent state dict ({what})")
    return state


def _unreadable(path: Path, message: str) -> str:
    """Why ``torch.load(path, weights_only=True)`` refused a file, without PyTorch's advice to load it with
    ``weights_only=False`` (which would run whatever code the file holds)."""
    found = re.search(r"Unsupported global: GLOBAL (\S+)", message)
    if found:
        return (f"policy.checkpoint={path} holds pickled Python code or objects ({found.group(1)}), not only "
                "tensors: GRT reads a ManiSkill checkpoint as tensors only, so no code in a file runs; save the "
                "agent's tensors (torch.save(agent.state_dict(), PATH), as ppo.py does)")
    head = path.read_bytes()[:2]
    if head[:1] == b"\x80" and head != b"PK":
        return (f"policy.checkpoint={path} is a plain pickle, not a torch checkpoint (torch.save writes a zip "
                "archive of tensors): save the agent's state_dict with torch.save(agent.state_dict(), PATH)")
    return f"policy.checkpoint={path} cannot be read as a torch state dict (not a torch file, or a damaged one)"


def build_actor(state: dict[str, torch.Tensor], activation: str = "tanh") -> nn.Sequential:
    """The actor-mean MLP of a ppo.py state dict: its Linear layers in index order, ``activation`` between.

    Raises:
        ManiSkillCheckpointError: layers whose shapes do not chain, or indices ppo.py's layout does not have.
    """
    layers: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in state.items():
        if (m := _LINEAR.fullmatch(key)) is not None:
            layers.setdefault(int(m.group(1)), {})[m.group(2)] = value
        elif key.startswith("actor_mean."):
            raise ManiSkillCheckpointError(f"{key}: the actor is not ppo.py's MLP (Linear layers with "
                                           f"{activation} between); load this checkpoint with its own code")
    order = sorted(layers)
    if order != list(range(0, 2 * len(order), 2)) or any(set(layers[i]) != {"weight", "bias"} for i in order):
        raise ManiSkillCheckpointError(f"actor_mean layers {order}: ppo.py's actor has Linear layers at 0, 2, 4, ... "
                                       "(an activation between each), each with a weight and a bias")
    modules: list[nn.Module] = []
    for n, i in enumerate(order):
        weight, bias = layers[i]["weight"], layers[i]["bias"]
        _check_layer(i, weight, bias)
        if modules and weight.shape[1] != modules[-2].out_features:
            raise ManiSkillCheckpointError(f"actor_mean.{i}.weight is {tuple(weight.shape)}: it does not take the "
                                           f"previous layer's {modules[-2].out_features} outputs")
        linear = nn.Linear(weight.shape[1], weight.shape[0])
        linear.load_state_dict({"weight": weight, "bias": bias})
        modules.append(linear)
        if n < len(order) - 1:
            modules.append(ACTIVATIONS[activation]())
    return nn.Sequential(*modules)


def _check_layer(i: int, weight, bias) -> None:
    """A Linear layer's tensors: a 2-D floating weight ``(out, in)`` and a 1-D floating bias ``(out,)``.

    Raises:
        ManiSkillCheckpointError: names the tensor, its shape and type, and what ppo.py's layer holds.
    """
    for name, value, dims in (("weight", weight, 2), ("bias", bias, 1)):
        if not (isinstance(value, torch.Tensor) and value.is_floating_point() and value.dim() == dims):
            what = f"{value.dtype} {tuple(value.shape)}" if isinstance(value, torch.Tensor) else type(value).__name__
            raise ManiSkillCheckpointError(f"actor_mean.{i}.{name} is {what}: a Linear layer's {name} is a "
                                           f"{dims}-D floating-point tensor ({'(outputs, inputs)' if dims == 2 else '(outputs,)'})")
    if bias.shape[0] != weight.shape[0]:
        raise ManiSkillCheckpointError(f"actor_mean.{i}.bias has {bias.shape[0]} values, its weight "
                                       f"{tuple(weight.shape)} {weight.shape[0]} outputs: they must agree")


class ManiSkillPPOPolicy(BatchedPolicy):
    """The actor of a ManiSkill PPO-baseline checkpoint on the env's flattened state observation.

    Args:
        checkpoint: the ``.pt`` file ppo.py saved (``Agent.state_dict()``).
        obs_group: the observation group holding the flattened state (``None``: the only group given).
        deterministic: act with the mean (ppo.py's evaluation) instead of sampling.
        activation: the actor's hidden activation (ppo.py: ``tanh``).
    """

    def __init__(self, checkpoint: str | None = None, obs_group: str | None = "state", deterministic: bool = True,
                 activation: str = "tanh"):
        if not checkpoint:
            raise ManiSkillCheckpointError("policy=maniskill_ppo needs policy.checkpoint=/path/to/ckpt.pt: the file "
                                           "ManiSkill's ppo.py saved (runs/<run>/final_ckpt.pt)")
        if activation not in ACTIVATIONS:
            raise ManiSkillCheckpointError(f"policy.activation={activation}: give one of {', '.join(ACTIVATIONS)}")
        self.path = str(checkpoint)
        state = read_agent(checkpoint)
        self.actor = build_actor(state, activation).eval()
        self.obs_size = int(self.actor[0].in_features)
        self.num_actions = int(self.actor[-1].out_features)
        logstd = state.get("actor_logstd")
        self.log_std = (logstd.reshape(-1) if logstd is not None else torch.zeros(self.num_actions)).float()
        if self.log_std.numel() != self.num_actions:
            raise ManiSkillCheckpointError(f"{self.path}: actor_logstd has {self.log_std.numel()} entries for "
                                           f"{self.num_actions} actions")
        self.obs_group, self.deterministic = obs_group, bool(deterministic)
        self.generator = torch.Generator().manual_seed(0)

    def check(self, task: str, obs_spec: dict, num_actions: int) -> None:
        """Refuse an env whose flattened state or action size is not the checkpoint's (one line naming both).

        Raises:
            ManiSkillCheckpointError: the sizes differ, or no observation group holds a flat state.
        """
        group = self._group(obs_spec)
        have = int(np.prod(obs_spec[group]))
        if have != self.obs_size or int(num_actions) != self.num_actions:
            raise ManiSkillCheckpointError(
                f"policy.checkpoint={self.path} takes a {self.obs_size}-D state and gives {self.num_actions} actions; "
                f"task {task} gives a {have}-D state ({group!r}) and takes {int(num_actions)} actions: use the "
                "env id, obs_mode=state and control_mode the checkpoint was trained with (ppo.py: pd_joint_delta_pos)")

    def _group(self, obs: dict) -> str:
        if self.obs_group is not None and self.obs_group in obs:
            return self.obs_group
        if len(obs) == 1:
            return next(iter(obs))
        raise ManiSkillCheckpointError(f"policy.obs_group={self.obs_group}: the task's observation groups are "
                                       f"{sorted(obs)}; name the one with the flattened state")

    def reset(self, seed: int) -> None:
        self.generator.manual_seed(int(seed))  # a sampled episode is a function of its seed

    @torch.inference_mode()
    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        state = np.asarray(obs[self._group(obs)], np.float32)
        x = torch.as_tensor(state.reshape(state.shape[0], -1))
        mean = self.actor(x)
        if not self.deterministic:
            mean = mean + torch.exp(self.log_std) * torch.randn(mean.shape, generator=self.generator)
        return mean.clamp(-1.0, 1.0).numpy()


def ppo_agent_state(grt_checkpoint: str | Path) -> dict[str, torch.Tensor]:
    """A GRT-trained policy (``python -m grt.train``) as ppo.py's ``Agent.state_dict()``, so that ManiSkill's
    own tools load it (``ppo.py --evaluate --checkpoint=...``): the observation normalizer is folded into the
    first layer of the actor and of the critic (exact: the normalizer is affine), the scalar std becomes
    ``actor_logstd``. ppo.py's ``Agent`` is 3 x 256 tanh layers on one flat observation group: a policy trained
    with that actor and critic (``conf/train/push_cube_state.yaml``) converts; another is refused.

    Raises:
        ManiSkillCheckpointError: a policy whose networks are not that MLP.
    """
    from grt.policies import rsl_rl

    ckpt = rsl_rl.load_checkpoint(grt_checkpoint)
    cfg = ckpt["grt"]["train_cfg"]
    groups = {tuple(g) for g in cfg["obs_groups"].values()}
    for name in ("actor", "critic"):
        net = cfg[name]
        if net.get("class_name") != "MLPModel" or net.get("activation") != "tanh" or len(groups) != 1 or \
                len(next(iter(groups))) != 1:
            raise ManiSkillCheckpointError(f"{grt_checkpoint}: its {name} is not ppo.py's MLP (an MLPModel with tanh "
                                           "activations on one observation group); it cannot be written as an Agent")
    out: dict[str, torch.Tensor] = {}
    for name, prefix in (("actor", "actor_mean"), ("critic", "critic")):
        state = ckpt[f"{name}_state_dict"]
        eps = 1e-2  # rsl_rl's EmpiricalNormalization default, which MLPModel uses
        scale = 1.0 / (state["obs_normalizer._std"].reshape(-1) + eps) if "obs_normalizer._std" in state else None
        shift = state["obs_normalizer._mean"].reshape(-1) if scale is not None else None
        for key, value in state.items():
            if not key.startswith("mlp."):
                continue
            index, what = key.split(".")[1:]
            value = value.detach().clone().float()
            if index == "0" and scale is not None:
                weight = state["mlp.0.weight"].float() * scale  # W (x - m) s + b = (W s) x + (b - W s m)
                value = weight if what == "weight" else value - weight @ shift
            out[f"{prefix}.{index}.{what}"] = value
    std = ckpt["actor_state_dict"].get("distribution.std_param")
    log_std = ckpt["actor_state_dict"].get("distribution.log_std_param")
    out["actor_logstd"] = (torch.log(std.float()) if std is not None else log_std.float()).reshape(1, -1)
    return out
