"""A cheap but real task session for the worker-pool tests (imported by spawned workers).

The "trial" drops seeded random points into the object's bounding box and asks whether enough of
them land inside the convex collision parts: it depends on the mesh, the parts and the seed only.
Switches make it misbehave on purpose: raise on a seed, kill its own process on a seed (always, or
only the first time, remembered through a marker file), hang on a seed (likewise), or fail to build. Its stock
object (a candidate ``None``, as a ManiSkill task's own actor) is :func:`stock_box`. ``continuous=True`` scores a
trial by a length in meters (the filled fraction times the object's height) instead of 0/1.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from grt.tasks.base import TaskSession


def stock_box() -> trimesh.Trimesh:
    """The toy task's own object: a 6 x 3 x 5 cm box resting on z = 0."""
    box = trimesh.creation.box((0.06, 0.03, 0.05))
    box.apply_translation([0.0, 0.0, 0.025])
    return box


class ToyPolicy:
    """Success threshold: the fraction of sampled points that must fall inside the object."""

    def __init__(self, fill: float = 0.5):
        self.fill = float(fill)


class ToySession(TaskSession):
    """Monte-Carlo 'trial' on the loaded object; see the module docstring."""

    def __init__(self, policy: ToyPolicy, samples: int = 400, raise_on: int | None = None,
                 crash_on: int | None = None, crash_once_marker: str | None = None, fail_build: bool = False,
                 continuous: bool = False, hang_on: int | None = None, hang_once_marker: str | None = None):
        if fail_build:
            raise RuntimeError("toy session refuses to build")
        self.policy, self.samples = policy, int(samples)
        self.raise_on, self.crash_on, self.marker = raise_on, crash_on, crash_once_marker
        self.hang_on, self.hang_marker = hang_on, hang_once_marker
        self.continuous = bool(continuous)
        self.equations: list[np.ndarray] = []
        self.bounds = np.zeros((2, 3))

    def load_objects(self, objects, assignment) -> None:
        mesh, parts = objects[assignment[0]]
        if mesh is None:  # the task's own (stock) object, as a ManiSkill task's actor
            mesh = stock_box()
            parts = [np.asarray(mesh.vertices)]
        if not parts:
            raise ValueError("no parts")
        self.equations = [ConvexHull(p).equations for p in parts]
        self.bounds = np.asarray(mesh.bounds)

    def _play(self, episodes) -> None:
        seed = episodes.seeds[0]
        if seed == self.crash_on and (self.marker is None or not Path(self.marker).exists()):
            if self.marker is not None:
                Path(self.marker).touch()
            os._exit(3)  # a hard crash: no exception, no cleanup
        if seed == self.hang_on and (self.hang_marker is None or not Path(self.hang_marker).exists()):
            if self.hang_marker is not None:
                Path(self.hang_marker).touch()
            time.sleep(3600)  # a hang: the process lives on and says nothing
        if seed == self.raise_on:
            raise RuntimeError(f"physics exploded on seed {seed}")
        rng = np.random.default_rng(seed)
        pts = rng.uniform(self.bounds[0], self.bounds[1], (self.samples, 3))
        inside = np.zeros(len(pts), bool)
        for eq in self.equations:
            inside |= (pts @ eq[:, :3].T + eq[:, 3]).max(axis=1) <= 0
        # A seed-dependent bar around the policy's threshold, so outcomes vary across seeds.
        bar = self.policy.fill + rng.uniform(-0.3, 0.3)
        fill = float(inside.mean())
        ok = fill >= bar
        self.last = f"seed {seed}: fill {fill:.3f}"
        score = fill * float(self.bounds[1, 2] - self.bounds[0, 2]) if self.continuous else float(ok)
        episodes.end(0, "success" if ok else "missed", score, {"fill": fill, "pid": os.getpid()})

    def render(self, path: str) -> None:
        """The 'picture' of the last trial: a text file (the protocol only needs ``render(path)``)."""
        Path(path).write_text(self.last)
