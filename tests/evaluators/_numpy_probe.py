"""A session that reports which numpy its worker runs and what crossed the pipe (the worker-path tests).

Imported by spawned workers that may run numpy 1.26 (``worker_path``): nothing here may need numpy 2.
"""

from __future__ import annotations

import numpy as np

from grt.tasks.base import TaskSession


class ProbePolicy:
    """A policy config with ``worker_path`` (the evaluator reads it; the class is given it too)."""

    def __init__(self, worker_path=None):
        self.worker_path = worker_path


class ProbeSession(TaskSession):
    """Sums the job's geometry; each trial answers with numpy objects of this worker's numpy."""

    def __init__(self, policy: ProbePolicy):
        self.policy, self.total = policy, None

    def load_objects(self, objects, assignment) -> None:
        mesh, parts = objects[assignment[0]]
        self.total = float(np.sum(mesh.vertices)) + float(np.sum(mesh.faces)) + sum(float(np.sum(p)) for p in parts)

    def _play(self, episodes) -> None:
        seed = episodes.seeds[0]  # a 0-d array: a float would be rounded to 6 digits in the outcome's info
        episodes.end(0, "success", np.float64(seed) / 10, {"numpy": np.__version__, "total": np.asarray(self.total),
                                                          "array": np.arange(3.0) * seed,
                                                          "ints": np.arange(2, dtype=np.int32)})


def numpy_version(offset: float) -> tuple[str, float]:
    """What :func:`grt.evaluators.worker_env.run_in_worker` runs in the tests: this process's numpy, and a sum."""
    return np.__version__, float(np.sum(np.arange(4.0)) + offset)


def refuse(reason: str) -> None:
    from grt.errors import UserError

    raise UserError(reason)
