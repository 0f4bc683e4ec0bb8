"""A task's score semantics: what one trial's score is, how it is named and bounded (:class:`ScoreSpec`), and
the nominal floor below which a run stops.

This module says *what* is measured; :mod:`grt.metrics` computes the run metrics *over* the scores (the
degradation curve, Final Drop, Iter@50%, AUC, ΔComplexity) and the intervals of a candidate's score. A task's
score settings are read from its config in one place, :meth:`ScoreSpec.from_task` (a run's ``summary.json``
stores the same fields, read back by :meth:`ScoreSpec.from_summary`).

A binary task (``score: success``, no ``score_unit``) scores a candidate by its success rate; a
continuous task (e.g. ``score: opening``, ``score_unit: m``) by the mean of a per-trial value. The red
team minimizes either, and every metric is relative to the nominal score ``S0``, so only what is
printed, plotted and stored needs the name and unit: everything that does goes through
:class:`ScoreSpec`, so outputs say "success rate" or "mean opening (m)".

Task config keys (all optional, so run folders written before they existed still load):

- ``score``: the name of the per-trial value (default ``success``).
- ``score_unit``: its unit (``m``, ``rad``...); ``""`` or absent for a binary task.
- ``ci``: the 95% interval of a candidate's score, one of :data:`grt.metrics.CI_METHODS`
  (default ``auto``: Wilson when every trial score is 0 or 1, else the normal approximation).
- ``nominal_floor``: the least nominal score ``S0`` worth red-teaming, in the score's unit; a run stops
  after its nominal evaluation below it (:func:`check_nominal_floor`). ``null`` turns it off; absent:
  :data:`BINARY_FLOOR` for a binary task, off for a continuous one (its unit is the task's own).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from grt.errors import UserError
from grt.metrics import CI_METHODS

# The paper keeps the objects the policy grasps in at least 25% of the nominal trials.
BINARY_FLOOR = 0.25
# A CrashShape scores at least this fraction of S0 below S0 (a drop of 10% or more); see crash_margin.
CRASH_MARGIN = 0.1


class ScoreConfigError(UserError):
    """A task's score settings cannot be used (unknown ``ci``, Wilson on a continuous score)."""


class NominalFloorError(UserError):
    """The nominal score ``S0`` is below the task's ``nominal_floor``: nothing worth red-teaming."""


@dataclass(frozen=True)
class ScoreSpec:
    """How a task's score is named, measured and bounded.

    Attributes:
        name: the task metric of one trial (``success``, ``opening``...).
        unit: its unit (``""`` for a binary or dimensionless score).
        ci: interval method of a candidate's mean score (see :func:`grt.metrics.score_interval`).
    """

    name: str = "success"
    unit: str = ""
    ci: str = "auto"

    def __post_init__(self) -> None:
        if self.ci not in CI_METHODS:
            raise ScoreConfigError(f"task.ci={self.ci!r}: use one of {', '.join(CI_METHODS)}")
        if self.ci == "wilson" and self.unit:
            raise ScoreConfigError(f"task.ci=wilson is the interval of a success rate, but the task's score "
                                   f"'{self.name}' is in {self.unit}: use task.ci=normal, bootstrap or auto")

    @classmethod
    def from_task(cls, task: Mapping | None) -> ScoreSpec:
        """The spec of a task config (a dict or DictConfig); absent or empty keys take their defaults."""
        task = task if task is not None else {}
        return cls._given(task.get("score"), task.get("score_unit"), task.get("ci"))

    @classmethod
    def from_summary(cls, summary: Mapping) -> ScoreSpec:
        """The spec stored in a ``summary.json`` (:meth:`fields`; summaries written before it: a success rate)."""
        return cls._given(summary.get("score_name"), summary.get("score_unit"), summary.get("ci"))

    @classmethod
    def _given(cls, name, unit, ci) -> ScoreSpec:
        """The spec of the given settings; ``None`` or ``""`` takes the field's default."""
        return cls(name=str(name or cls.name), unit=str(unit or cls.unit), ci=str(ci or cls.ci))

    @property
    def binary(self) -> bool:
        """Whether the candidate's score is a success rate."""
        return self.name == "success" and not self.unit

    @property
    def title(self) -> str:
        """What a candidate's score is, without its unit: ``success rate`` or ``mean opening``."""
        return "success rate" if self.binary else f"mean {self.name}"

    @property
    def label(self) -> str:
        """An axis or column label: ``success rate`` or ``mean opening (m)``."""
        return self.title + (f" ({self.unit})" if self.unit else "")

    def fmt(self, value: float | None, unit: bool = False) -> str:
        """A score for people: ``0.81`` for a success rate, ``0.3512`` (``0.3512 m`` with ``unit``) else;
        ``-`` for a missing or NaN score."""
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return "-"
        text = f"{value:.2f}" if self.binary else f"{value:.4g}"
        return f"{text} {self.unit}" if unit and self.unit else text

    def fields(self) -> dict:
        """JSON fields naming the score (``summary.json``, ``evaluate``'s last line)."""
        return {"score_name": self.name, "score_unit": self.unit, "ci": self.ci}


def nominal_floor(task: Mapping | None) -> float | None:
    """The task's ``nominal_floor`` (``None``: off); absent, :data:`BINARY_FLOOR` for a binary task, else off.

    Raises:
        ScoreConfigError: a value that is not a finite number or null.
    """
    task = task if task is not None else {}
    if "nominal_floor" not in task:
        return BINARY_FLOOR if ScoreSpec.from_task(task).binary else None
    value = task["nominal_floor"]
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScoreConfigError(f"task.nominal_floor={value!r}: give a number in the task's score unit, or null "
                               "to turn the floor off")
    return float(value)


def crash_margin(task: Mapping | None) -> float:
    """The task's ``crash_margin``: the least relative drop ``(S0 - score) / S0`` that makes a candidate a
    CrashShape (absent: :data:`CRASH_MARGIN`). A candidate that scores as the nominal object did is no failure.

    Raises:
        ScoreConfigError: a value that is not a number in [0, 1).
    """
    value = (task if task is not None else {}).get("crash_margin", CRASH_MARGIN)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < 1:
        raise ScoreConfigError(f"task.crash_margin={value!r}: give the least drop below S0 that makes a CrashShape, "
                               "as a fraction of S0 in [0, 1) (0.1: 10%)")
    return float(value)


def is_crash(score: float, s0: float, margin: float) -> bool:
    """Whether a candidate's ``score`` is below ``s0`` by ``margin`` of ``s0`` (never when S0 <= 0 or NaN)."""
    return bool(s0 > 0 and score == score and score < s0 and (s0 - score) / s0 >= margin - 1e-12)


def check_nominal_floor(s0: float, floor: float | None, spec: ScoreSpec, resume: str | None = None) -> None:
    """Stop a run whose nominal score is below ``floor`` (``None``: never).

    Args:
        s0: the nominal score; floor: the task's :func:`nominal_floor`; spec: the task's score.
        resume: the command that continues the run (``python -m grt.run resume=DIR``), named in the message.

    Raises:
        NominalFloorError: one line naming ``S0``, the floor and what to do.
    """
    if floor is None or not s0 < floor:
        return
    lower = f"{floor / 2:.2g}"
    where = f"{resume} task.nominal_floor={lower}" if resume else \
        f"task.nominal_floor={lower}"
    raise NominalFloorError(
        f"S0 = {spec.fmt(s0, unit=True)} ({spec.label} on the nominal object) is below task.nominal_floor = "
        f"{spec.fmt(floor, unit=True)}: the policy already fails on this object, so there is little to red-team. "
        f"Choose another object or policy, or lower the floor ({where}; null turns it off)")
