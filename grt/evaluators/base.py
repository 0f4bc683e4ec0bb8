"""Evaluator interface: candidate meshes in, one score per candidate out.

Every candidate of one :meth:`Evaluator.evaluate` call is scored on the same episode seeds (common
random numbers, the paper's protocol): differences between candidates then come from their shapes,
not from the luck of the draw.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import trimesh

from grt.errors import UserError
from grt.metrics import score_interval
from grt.tasks.base import SIM_ERROR, TrialOutcome


@dataclass
class CandidateResult:
    """The score of one candidate and the trials behind it.

    Attributes:
        score: the task metric averaged over the trials that ran (``sim_error`` trials excluded:
            a simulator failure says nothing about the policy); NaN when every trial errored.
        trials: one :class:`TrialOutcome` per seed, in the order of the seeds given.
        wall_s: seconds of worker time spent on this candidate (object loading + trials).
    """

    score: float
    trials: list[TrialOutcome]
    wall_s: float
    info: dict = field(default_factory=dict)

    @classmethod
    def from_trials(cls, trials: list[TrialOutcome], wall_s: float, info: dict | None = None) -> CandidateResult:
        """Build a result, computing ``score`` from the trials."""
        valid = [t.score for t in trials if t.mode != SIM_ERROR]
        score = float(np.mean(valid)) if valid else float("nan")
        return cls(score=score, trials=list(trials), wall_s=float(wall_s), info=dict(info or {}))

    @property
    def valid_trials(self) -> list[TrialOutcome]:
        """Trials that ran to an outcome (all but ``sim_error``)."""
        return [t for t in self.trials if t.mode != SIM_ERROR]

    @property
    def success_rate(self) -> float:
        """Fraction of valid trials that succeeded (NaN without valid trials)."""
        valid = self.valid_trials
        return sum(t.success for t in valid) / len(valid) if valid else float("nan")

    @property
    def outcomes(self) -> dict[str, int]:
        """Trial count per outcome mode (``success``, ``missed``, ..., ``sim_error``)."""
        return dict(Counter(t.mode for t in self.trials))

    @property
    def sim_errors(self) -> int:
        return sum(t.mode == SIM_ERROR for t in self.trials)

    def ci95(self, method: str = "auto") -> tuple[float, float]:
        """95% interval of ``score`` over the valid trials (NaN without any).

        Args:
            method: the task's ``ci`` setting: ``auto`` (Wilson when every trial scored 0 or 1, else
                the normal approximation), ``wilson``, ``normal`` or ``bootstrap``; see
                :func:`grt.metrics.score_interval`.
        """
        return score_interval([t.score for t in self.valid_trials], method)

    def summary(self, ci: str = "auto") -> dict:
        """JSON-ready figures: score, success_rate, trials, outcomes, ci95 (by ``ci``), wall_s."""
        low, high = self.ci95(ci)
        return {"score": self.score, "success_rate": self.success_rate, "trials": len(self.trials),
                "outcomes": self.outcomes, "ci95": [low, high], "wall_s": self.wall_s}


class NothingScoredError(UserError):
    """Every trial of an object ended in ``sim_error`` (a policy's unusable output, a simulator that cannot
    build the object...): it has no score, and nothing built on it (S0, a drop) could be trusted."""


def check_scored(result: CandidateResult, what: str) -> None:
    """Raise :class:`NothingScoredError` when every trial of ``result`` (of ``what``, e.g. "the nominal object")
    ended in ``sim_error``, naming the first trial's reason."""
    if not result.trials or result.sim_errors < len(result.trials):
        return
    first = next((t for t in result.trials if t.info.get("error")), result.trials[0])
    reason = str(first.info.get("error") or "no reason recorded").strip().splitlines()[0][:400]
    raise NothingScoredError(f"every trial on {what} ({len(result.trials)}) ended in sim_error, so it has no score; "
                             f"the first (seed {first.seed}): {reason}")


class Evaluator(ABC):
    """Scores candidate meshes by simulated trials of a policy. Use as a context manager."""

    #: Whether :meth:`evaluate_each` stops a candidate's trials early when given ``race`` (``budget.racing``);
    #: one that does not runs every trial, and a run that asked for racing says so.
    races = False

    @abstractmethod
    def evaluate(self, meshes: list[trimesh.Trimesh], seeds: list[int]) -> list[CandidateResult]:
        """Score every mesh on the same episode seeds.

        Args:
            meshes: candidate meshes in meters (z up, resting on z = 0, centered in x/y).
            seeds: episode seeds, the same for every candidate (common random numbers).

        Returns:
            One :class:`CandidateResult` per mesh, in order; its trials follow ``seeds``.
        """

    def evaluate_each(self, meshes: list[trimesh.Trimesh], seeds: list[int],
                      on_result: Callable[[int, CandidateResult], None], race=None) -> list[CandidateResult]:
        """:meth:`evaluate`, calling ``on_result(i, result)`` as soon as mesh ``i``'s trials are all in.

        The red-team loop scores a whole population in one call this way and journals each candidate
        as it finishes, so a killed run loses little. This default calls back after :meth:`evaluate`,
        in order; :class:`grt.evaluators.sim.SimEvaluator` calls back while the other meshes still run.
        ``race`` (:class:`grt.racing.Race`): stop a mesh's trials in rounds once it cannot matter
        (:class:`~grt.evaluators.sim.SimEvaluator` does); this default runs every trial, which is always
        correct (a full-trial result is what racing would have kept for a candidate that matters).
        """
        results = self.evaluate(meshes, seeds)
        for i, result in enumerate(results):
            on_result(i, result)
        return results

    @abstractmethod
    def collision_parts(self, mesh: trimesh.Trimesh) -> list[np.ndarray]:
        """The convex parts ``(K, 3)`` (meters) the simulator uses for ``mesh`` (saved with CrashShapes)."""

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release workers and simulators."""

    def __enter__(self) -> Evaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def evaluator_preflight(evaluator: dict, task: dict, policy: dict) -> None:
    """Refuse, before a command writes anything, what the configured evaluator cannot run: the evaluator
    class's own ``preflight(task=, policy=, **its config)`` when it has one (``evaluator=gpu``: a task or a
    policy that cannot run batched, no CUDA); the CPU evaluators run every task and have none.

    Args:
        evaluator: the evaluator config as a plain dict (``_target_`` and its keys).
        task, policy: the task and policy configs as plain dicts.
    """
    from hydra.utils import get_object

    check = getattr(get_object(str(evaluator["_target_"])), "preflight", None)
    if check is not None:
        check(task=task, policy=policy, **{k: v for k, v in evaluator.items() if not k.startswith("_")})
