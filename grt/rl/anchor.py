"""Keep a fine-tuned policy close to the one it started from, where it already worked.

Blue-teaming fine-tunes a policy on CrashShapes plus the nominal object. PPO on that mix still drifts
on the nominal object (measured on the point-cloud insertion policy: its nominal validation fell from
32/32 to 16-19/32 by iteration 150-180 with half of the training episodes on the nominal plug). The
anchor is a distillation term in the spirit of "learning without forgetting": the states the policy
before fine-tuning visits on the nominal object (its own rollouts, its actions perturbed a little so
the states around its path are covered) are recorded once with that policy's mean actions; after each
PPO iteration a few gradient steps pull the actor's mean action on those states back toward them.
States of the CrashShapes are not in the set, so the actor stays free to act differently there.

Measured (joint fine-tune of the point-cloud insertion policy on 3 CrashShapes): with 8 steps per
iteration the nominal validation stayed at 32/32 and the CrashShapes at 0.27-0.40 (0.33 before) for
60 iterations; with 2 steps the same, up to 0.46 at iteration 100 and back to 0.31-0.44, and the
exported checkpoint scored the CrashShapes as before. The states that matter to the CrashShapes are
close to the nominal ones for this policy, so holding one holds the other. It is off by default
(``blueteam.anchor.updates=0``).
"""

from __future__ import annotations

import copy

import torch


class NominalAnchor:
    """Recorded states with the reference policy's actions, and the steps that pull an actor to them.

    Args:
        data: the recorded observations (a TensorDict, flat over steps and envs).
        targets: the reference actor's mean actions on ``data``.
        updates: Adam steps per PPO iteration (the anchor's strength; Adam's step does not scale with the
            loss, so the number of steps is the knob).
        batch: states per step.
        lr: the anchor's learning rate.
        seed: the batches' generator.
    """

    def __init__(self, data, targets: torch.Tensor, updates: int = 8, batch: int = 256, lr: float = 1e-4,
                 seed: int = 0):
        if updates < 0 or batch < 1 or len(targets) == 0:
            raise ValueError(f"anchor: updates={updates}, batch={batch}, {len(targets)} states: give updates >= 0, "
                             "batch >= 1 and at least one recorded step")
        self.data, self.targets = data, targets
        self.updates, self.batch, self.lr = int(updates), int(batch), float(lr)
        self.gen = torch.Generator().manual_seed(int(seed))
        self.optim = None

    @classmethod
    def record(cls, actor, env, steps: int, noise: float = 0.1, seed: int = 0, **kwargs) -> NominalAnchor:
        """Roll ``actor`` (as it is now: the reference) in ``env`` (the nominal object only) for ``steps``
        steps per env, acting with its mean action plus Gaussian ``noise``; record the states and the
        mean actions."""
        reference = copy.deepcopy(actor).eval()
        gen = torch.Generator().manual_seed(int(seed))
        obs, states = env.get_observations(), []
        with torch.no_grad():
            for _ in range(int(steps)):
                states.append(obs.clone())
                act = reference(obs)
                obs, *_ = env.step((act + noise * torch.randn(act.shape, generator=gen)).clamp(-1.0, 1.0))
            data = torch.stack(states).reshape(-1)
            targets = reference(data)
        return cls(data, targets, seed=seed, **kwargs)

    def error(self, actor) -> float:
        """Mean squared distance of ``actor``'s mean actions from the reference's over every recorded state."""
        with torch.no_grad():
            return float(((actor(self.data) - self.targets) ** 2).mean())

    def step(self, actor) -> float:
        """``updates`` Adam steps of the actor's mean toward the reference actions; returns the last loss."""
        params = [p for name, p in actor.named_parameters() if "std" not in name]  # the exploration noise is PPO's
        if self.optim is None:
            self.optim = torch.optim.Adam(params, lr=self.lr)
        loss = torch.zeros(())
        for _ in range(self.updates):
            idx = torch.randint(0, len(self.targets), (min(self.batch, len(self.targets)),), generator=self.gen)
            loss = ((actor(self.data[idx]) - self.targets[idx]) ** 2).mean()
            self.optim.zero_grad()
            loss.backward()
            self.optim.step()
        return float(loss.detach())
