"""Policies trained with rsl-rl, loaded from a checkpoint that carries its own config.

A GRT checkpoint is rsl-rl's own save dict (``actor_state_dict``, ``critic_state_dict``, ``iter``,
...) plus a ``grt`` entry (as diffusion_policy stores its config inside every checkpoint)::

    {"task": "insertion", "obs_spec": {"state": [24], "cloud": [500, 3]}, "num_actions": 6,
     "train_cfg": {... the rsl-rl runner config: obs_groups, actor, critic, algorithm ...},
     "task_cfg": {... the task session's config at training time ...}, "metrics": {...}}

so the actor can be rebuilt from the file alone, and a checkpoint made for another task or another
observation size is refused with a message naming both.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from rsl_rl.utils import resolve_class
from tensordict import TensorDict

from grt.errors import UserError
from grt.policies.base import BatchedPolicy, observation_groups


class CheckpointError(UserError):
    """A checkpoint that is missing, unreadable, or made for another task or observation."""


def load_checkpoint(path: str | Path) -> dict:
    """The checkpoint dict at ``path`` (CPU tensors).

    Raises:
        CheckpointError: missing or unreadable file, or no ``grt`` config inside.
    """
    path = Path(path).expanduser()
    if path.is_dir():
        inside = ", ".join(p.name for p in sorted(path.glob("*.pt"))[:3]) or "no .pt file"
        raise CheckpointError(f"policy checkpoint {path} is a folder ({inside} in it): give the .pt file "
                              "(a training's policy.pt)")
    if not path.is_file():
        raise CheckpointError(f"policy checkpoint {path} does not exist: train one with "
                              "`python -m grt.train ...` or point policy.checkpoint at a .pt file")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:
        raise CheckpointError(f"policy checkpoint {path} cannot be read ({type(err).__name__}: {err}); it is "
                              "corrupt or not a torch file: re-train or re-download it") from err
    if not isinstance(ckpt, dict) or "grt" not in ckpt or "actor_state_dict" not in ckpt:
        raise CheckpointError(f"{path} is not a GRT rsl-rl checkpoint (no 'grt' config or actor weights inside): "
                              "checkpoints written by python -m grt.train carry both")
    return ckpt


def dummy_obs(obs_spec: dict, batch: int = 1) -> TensorDict:
    """Zero observations of the given spec (``{group: shape}``), batched."""
    return TensorDict({k: torch.zeros((batch, *v)) for k, v in obs_spec.items()}, batch_size=[batch])


def build_actor(grt_cfg: dict):
    """The rsl-rl actor model described by a checkpoint's ``grt`` config (untrained weights)."""
    train = grt_cfg["train_cfg"]
    actor_class, actor_cfg = resolve_class(dict(train["actor"]))
    obs = dummy_obs(grt_cfg["obs_spec"])
    return actor_class(obs, train["obs_groups"], "actor", int(grt_cfg["num_actions"]), **actor_cfg)


class RslRlPolicy(BatchedPolicy):
    """An rsl-rl actor from a GRT checkpoint, acting deterministically (the distribution's mean).

    Args:
        checkpoint: path of the ``.pt`` file.
        task: the task name the policy must have been trained for (``None``: not checked here).
        deterministic: act with the mean action (evaluation; the default) instead of sampling from
            the policy's distribution (torch's global generator, seeded per episode).
        device: torch device.
    """

    def __init__(self, checkpoint: str, task: str | None = None, deterministic: bool = True,
                 device: str = "cpu"):
        self.path = str(checkpoint)
        ckpt = load_checkpoint(checkpoint)
        self.config: dict = ckpt["grt"]
        self.obs_spec = {k: tuple(v) for k, v in self.config["obs_spec"].items()}
        self.num_actions = int(self.config["num_actions"])
        if task is not None and self.config["task"] != task:
            raise CheckpointError(f"checkpoint {self.path} was trained for task {self.config['task']!r}, not "
                                  f"{task!r}: pick the policy made for {task!r} or train one")
        self.actor = build_actor(self.config)
        try:
            self.actor.load_state_dict(ckpt["actor_state_dict"])
        except RuntimeError as err:
            raise CheckpointError(f"checkpoint {self.path}: weights do not fit the stored model config: {err}") from err
        self.actor.to(device).eval()
        self.device, self.deterministic = device, bool(deterministic)

    @property
    def input_spec(self) -> dict[str, tuple[int, ...]]:
        """The observation groups the actor reads (of :attr:`obs_spec`, which may hold more)."""
        groups = self.config["train_cfg"]["obs_groups"].get("actor") or sorted(self.obs_spec)
        return {g: self.obs_spec[g] for g in groups if g in self.obs_spec}

    @property
    def task(self) -> str:
        return str(self.config["task"])

    def check(self, task: str, obs_spec: dict, num_actions: int) -> None:
        """Refuse a task whose name, observation groups or action size differ from the training's.

        Raises:
            CheckpointError: naming both sides.
        """
        if task != self.task:
            raise CheckpointError(f"checkpoint {self.path} was trained for task {self.task!r}, but the run's task "
                                  f"is {task!r}: use a policy trained for {task!r}")
        needed = {g for groups in self.config["train_cfg"]["obs_groups"].values() for g in groups}
        for group in sorted(needed):
            want = self.obs_spec.get(group)
            have = tuple(obs_spec[group]) if group in obs_spec else None
            if have is None:
                groups = observation_groups(obs_spec)
                raise CheckpointError(f"checkpoint {self.path} reads observation {group!r} of shape {want}, which the "
                                      f"task does not give (it gives {groups}): run the task with the observation "
                                      "mode the policy was trained on (e.g. task.session.obs_mode) or use another "
                                      "checkpoint")
            if have != want:
                raise CheckpointError(f"checkpoint {self.path} expects observation {group!r} of shape {want}, the "
                                      f"task gives {have}: set the task's observation size to match (e.g. "
                                      "task.session.cloud_points) or use another checkpoint")
        if num_actions != self.num_actions:
            raise CheckpointError(f"checkpoint {self.path} outputs {self.num_actions} actions, the task takes "
                                  f"{num_actions}")

    def reset(self, seed: int) -> None:
        if not self.deterministic:
            torch.manual_seed(int(seed))  # a sampled episode is still a function of its seed

    @torch.inference_mode()
    def act(self, obs: dict) -> np.ndarray:
        """Actions ``(N, A)`` for observation groups ``{group: (N, ...)}``: numpy arrays in, a numpy array out
        (moved to :attr:`device` and back: one batch per call, the GPU evaluator's ``(N, obs)``), or torch
        tensors in, a tensor on :attr:`device` out."""
        batch = next(iter(obs.values())).shape[0]
        tensors = any(isinstance(v, torch.Tensor) for v in obs.values())
        td = TensorDict({k: torch.as_tensor(v, dtype=torch.float32, device=self.device)
                         for k, v in obs.items() if k in self.obs_spec}, batch_size=[batch])
        action = self.actor(td, stochastic_output=not self.deterministic).clamp(-1.0, 1.0)
        return action if tensors else action.cpu().numpy()
