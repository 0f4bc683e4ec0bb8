"""Task sessions: what the evaluator drives, one simulator per worker process.

A :class:`TaskSession` owns one simulated environment for its whole life. The evaluator swaps the
object (``load_object``: a reconfigure, tens of milliseconds) and then runs seeded trials
(``run_trial``), each ending in a :class:`TrialOutcome` with a named failure mode — a trial never
fails or succeeds silently.

Failure modes shared by tasks (a task may add its own):

- ``success``: the task's success condition holds at the end of the trial.
- ``no_grasp_found``: the policy proposed nothing it would execute (after its retries).
- ``unreachable``: inverse kinematics found no joint configuration for any proposal.
- ``missed``: the gripper closed on nothing.
- ``dropped_lift`` / ``dropped_shake``: the object was held, then lost while lifting / shaking.
- ``sim_error``: the simulation itself failed (NaN state, object flying away, a physics exception).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

FAILURE_MODES = (
    "success",
    "no_grasp_found",
    "unreachable",
    "missed",
    "dropped_lift",
    "dropped_shake",
    "sim_error",
)


@dataclass
class TrialOutcome:
    """The result of one seeded trial.

    Attributes:
        seed: the episode seed (object pose randomization and the policy's sampling).
        score: the task metric of this trial (1.0 / 0.0 for binary tasks).
        success: whether the task succeeded.
        mode: one of :data:`FAILURE_MODES` (or a task-specific mode), never empty.
        info: JSON-serializable details (timings in seconds, grasp width in meters, ...).
    """

    seed: int
    score: float
    success: bool
    mode: str
    info: dict[str, Any] = field(default_factory=dict)


class TaskSession(ABC):
    """One environment, many objects, many trials. Subclasses take plain typed arguments.

    Usage (what an evaluator worker does)::

        session = hydra.utils.instantiate(task_cfg.session, policy=policy)
        session.load_object(mesh, parts)
        outcomes = [session.run_trial(seed) for seed in seeds]
        session.close()
    """

    #: Name of the task metric; ``success`` means binary (score = float(success)).
    score_name: str = "success"

    @abstractmethod
    def load_object(self, mesh: trimesh.Trimesh, parts: list[np.ndarray]) -> None:
        """Rebuild the scene around a new object.

        Args:
            mesh: the visual mesh, meters, z up, resting on z = 0, centered in x/y.
            parts: convex collision parts, each a ``(K, 3)`` vertex array in the mesh's frame (m).

        Raises:
            ValueError: if ``parts`` is empty or a part does not build into a collision shape.
        """

    @abstractmethod
    def run_trial(self, seed: int) -> TrialOutcome:
        """Run one episode on the loaded object; deterministic given ``seed``."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the simulator."""

    def __enter__(self) -> TaskSession:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
