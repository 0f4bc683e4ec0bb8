"""Neural models for rsl-rl policies that see point clouds: a small PointNet encoder before the MLP.

:class:`PointNetModel` is an rsl-rl ``MLPModel`` (so PPO, storage, checkpoints and export work as for
any rsl-rl model) whose 2-D observation groups ``(N, P, 3)`` go through a shared PointNet encoder
(per-point MLP, max pool) and whose 1-D groups are normalized and concatenated with the encoding.
The paper uses a reduced PointNet++ producing a 32-D feature; this is the PointNet core of it.
"""

from __future__ import annotations

import torch
import torch.nn as nn
from rsl_rl.models import MLPModel
from tensordict import TensorDict


class PointNetEncoder(nn.Module):
    """Per-point MLP then max pooling: ``(N, P, 3)`` -> ``(N, out_dim)``.

    Args:
        hidden: widths of the shared per-point layers.
        out_dim: size of the pooled feature (the paper: 32).
        scale: points are divided by this (m) first, so typical coordinates are O(1).
    """

    def __init__(self, hidden: tuple[int, ...] = (64, 128), out_dim: int = 32, scale: float = 0.05):
        super().__init__()
        layers, width = [], 3
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ELU()]
            width = h
        layers.append(nn.Linear(width, out_dim))
        self.point_mlp = nn.Sequential(*layers)
        self.out_dim, self.scale = int(out_dim), float(scale)

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return self.point_mlp(points / self.scale).max(dim=-2).values


class PointNetModel(MLPModel):
    """An rsl-rl MLP model with a PointNet encoder for its point-cloud groups.

    Args:
        obs, obs_groups, obs_set, output_dim, hidden_dims, activation, obs_normalization,
            distribution_cfg: as :class:`rsl_rl.models.MLPModel`.
        pointnet: :class:`PointNetEncoder` keyword arguments.
    """

    def __init__(self, obs: TensorDict, obs_groups: dict[str, list[str]], obs_set: str, output_dim: int,
                 hidden_dims=(256, 256, 256), activation: str = "elu", obs_normalization: bool = False,
                 distribution_cfg: dict | None = None, pointnet: dict | None = None):
        groups = obs_groups[obs_set]
        self.cloud_groups = [g for g in groups if obs[g].dim() == 3]
        self._pointnet_cfg = dict(pointnet or {})
        flat = {**obs_groups, obs_set: [g for g in groups if g not in self.cloud_groups]}
        super().__init__(obs, flat, obs_set, output_dim, hidden_dims, activation, obs_normalization,
                         distribution_cfg)

    def _get_latent_dim(self) -> int:
        self.encoders = nn.ModuleDict({g: PointNetEncoder(**self._pointnet_cfg) for g in self.cloud_groups})
        return self.obs_dim + sum(e.out_dim for e in self.encoders.values())

    def get_latent(self, obs: TensorDict, masks=None, hidden_state=None) -> torch.Tensor:
        flat = self.obs_normalizer(torch.cat([obs[g] for g in self.obs_groups], dim=-1))
        clouds = [self.encoders[g](obs[g]) for g in self.cloud_groups]
        return torch.cat([flat, *clouds], dim=-1)
