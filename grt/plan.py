"""The run as a plan: one red-team run's settings, parsed once into typed values.

:func:`grt.config.make_plan` turns the composed Hydra config (or a run folder's saved one) into a
:class:`RunPlan`; everything after it (the runner, the outputs, the scores, the confirmation, the reports)
reads the plan, never the config. Values the run derives from its settings are derived here, once: the
score spec, the nominal floor, the crash margin (:attr:`RunPlan.crash_margin`), the Smoothness-Score cap
(:meth:`RunPlan.smoothness_cap`), racing (:meth:`RunPlan.racing`) and the number of candidates.

:class:`Budget` declares the numbers of a search once: their defaults, what each accepts (:class:`Rule`) and
what it means; the ``budget`` group's Hydra schema is made from it (:data:`grt.config.BudgetSchema`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from grt.agreement import SwapCheckSettings
from grt.geometry.deform import DEFAULT_RADIUS, deformer_options
from grt.geometry.prepare import MeshSettings
from grt.geometry.quality import candidate_validity
from grt.optimizers.smoothness import budget_tau
from grt.racing import Racing
from grt.scores import ScoreSpec, crash_margin, nominal_floor


@dataclass(frozen=True)
class Rule:
    """What one setting accepts: ``check(value) -> bool``, described by ``accepts`` in messages."""

    accepts: str
    check: Callable[[Any], bool]


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def at_least(low: int) -> Rule:
    """An integer setting with a lower bound."""
    return Rule(f"an integer >= {low}", lambda v: _is_int(v) and v >= low)


POSITIVE = Rule("a finite number > 0", _is_positive)
POSITIVE_OR_NULL = Rule("null (off) or a finite number > 0", lambda v: v is None or _is_positive(v))
BOOLEAN = Rule("true or false", lambda v: isinstance(v, bool))
NON_NEGATIVE = Rule("a finite number >= 0",
                    lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0)
FRACTION = Rule("a number strictly between 0 and 1",
                lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and 0 < v < 1)
RISK = Rule("a number in [0, 0.5) (0: only stop a candidate that cannot matter even if every trial left fails)",
            lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v < 0.5)


def _setting(default, rule: Rule, meaning: str):
    return field(default=default, metadata={"rule": rule, "meaning": meaning})


@dataclass(frozen=True)
class Budget:
    """The numbers of a search (paper appendix, lines 1062-1099); each field's :class:`Rule` is in its metadata.

    Attributes:
        population: candidates per iteration (paper: 10).
        iterations: ``T`` (paper: 10).
        trials: simulated episodes per candidate (paper: 64 for grasping).
        sigma: std of the Gaussian over handle displacements, unit-cube units (paper: 0.001).
        seed: seeds the optimizer and the episode seeds (paper: 42).
        workers: simulator worker processes.
        tau: Smoothness-Score budget in meters (``None``: off, or ``tau_rel``'s).
        tau_rel: the budget relative to the object: a fraction of its bounding-box diagonal, converted to
            meters per object (:func:`grt.optimizers.smoothness.budget_tau`); used when ``tau`` is ``None``.
        top_k: CrashShapes saved in the run folder.
        confirm_trials: fresh episodes on which the nominal object and each CrashShape are scored again
            after the search, with a paired test of each drop (:mod:`grt.confirm`); 0 turns it off.
        videos: CrashShapes whose failing trial (and the nominal object's on the same seed) are filmed
            for ``report.html`` after the search (:mod:`grt.rerun`); 0 turns it off. ``report.videos``
            of ``conf/run.yaml`` reads it.
        racing: run each candidate's trials in rounds and stop it once it cannot be a CrashShape among the
            ``top_k`` (:mod:`grt.racing`); off: every candidate runs every trial (as before racing existed).
        race_rounds: rounds of about equal size a raced candidate's trials run in (at most one per trial).
        race_alpha: the most probability with which racing stops a candidate that would have mattered.
        shrink: after the confirmation, shrink each confirmed CrashShape to the smallest scale of its
            displacements whose drop is still confirmed on fresh episodes (:mod:`grt.shrink`).
        shrink_ratio: each level of the shrink scales the displacements by this much more (0.7: 0.7, 0.49,
            ...); shrink_min_alpha: the smallest scale tried.
        shrink_rounds: rounds of about equal size a level's episodes run in (its trials stop at the first
            round after which its answer is clear).
        size_penalty: a search for the smallest CrashShape: each candidate's score as the search sees it gets
            ``size_penalty x S0 x SS / tau`` added (SS its Smoothness Score, tau the run's cap, or 0.087 of the
            diagonal without one), so of two candidates that fail alike it keeps the smaller; 0: off.
    """

    population: int = _setting(10, at_least(1), "candidates per iteration")
    iterations: int = _setting(10, at_least(1), "search iterations T")
    trials: int = _setting(64, at_least(1), "simulated episodes per candidate")
    sigma: float = _setting(0.001, POSITIVE, "std of the handle displacements, unit-cube units")
    seed: int = _setting(42, at_least(0), "seed of the optimizer and of the episode seeds")
    workers: int = _setting(2, at_least(1), "simulator worker processes")
    tau: float | None = _setting(None, POSITIVE_OR_NULL, "Smoothness-Score budget in meters")
    tau_rel: float | None = _setting(None, POSITIVE_OR_NULL, "Smoothness-Score budget as a fraction of the "
                                     "object's bounding-box diagonal (used when budget.tau is null)")
    top_k: int = _setting(3, at_least(1), "CrashShapes saved in the run folder")
    confirm_trials: int = _setting(0, at_least(0), "fresh episodes re-scoring the nominal object and each "
                                   "CrashShape after the search (0: off)")
    videos: int = _setting(3, at_least(0), "CrashShapes filmed for report.html after the search (0: off)")
    racing: bool = _setting(False, BOOLEAN, "race each candidate's trials in rounds, stopping one that cannot "
                            "matter")
    race_rounds: int = _setting(8, at_least(2), "rounds a raced candidate's trials run in")
    race_alpha: float = _setting(0.05, RISK, "the most probability of stopping a candidate that would have "
                                 "mattered")
    shrink: bool = _setting(True, BOOLEAN, "shrink each confirmed CrashShape to its smallest confirmed scale")
    shrink_ratio: float = _setting(0.7, FRACTION, "the scale of each shrink level relative to the one before")
    shrink_min_alpha: float = _setting(0.05, FRACTION, "the smallest scale of a CrashShape the shrink tries")
    shrink_rounds: int = _setting(8, at_least(1), "rounds a shrink level's episodes run in")
    size_penalty: float = _setting(0.0, NON_NEGATIVE, "a search for the smallest CrashShape: the search is told "
                                   "score + size_penalty x S0 x (mean handle displacement / the cap tau); 0: off")

    @classmethod
    def of(cls, budget: Mapping) -> Budget:
        """The budget of a config's ``budget`` mapping (checked by :func:`grt.config.check_budget`); a key a
        run from before it lacks takes its default."""
        return cls(**{f.name: budget.get(f.name, f.default) for f in fields(cls)})

    @property
    def candidates(self) -> int:
        """Candidates a finished run's journal holds: the nominal object and ``population`` per iteration."""
        return 1 + self.population * self.iterations


BUDGET_KEYS = tuple(f.name for f in fields(Budget))


@dataclass(frozen=True)
class DeformerPlan:
    """The deformation model and the plausibility check of a run's candidates (the ``deformer`` block).

    Attributes:
        method, lam, radius: :class:`grt.geometry.deform.ShapeDeformer`'s (a run from before a key: the value
            it was made with).
        validity: check each candidate for self-intersections and folds before simulating it.
        max_volume_change: ... and refuse one whose volume changed by more than this fraction (``None``: not
            checked).
    """

    method: str = "exact"
    lam: float = 1.0
    radius: float = DEFAULT_RADIUS
    validity: bool = False
    max_volume_change: float | None = None

    @classmethod
    def of(cls, deformer: Mapping) -> DeformerPlan:
        """The plan of a config's ``deformer`` mapping."""
        return cls(**deformer_options(deformer), validity=bool(deformer.get("validity")),
                   max_volume_change=deformer.get("max_volume_change"))

    @property
    def options(self) -> dict:
        """:class:`grt.geometry.deform.ShapeDeformer`'s keyword arguments."""
        return {"lam": self.lam, "method": self.method, "radius": self.radius}

    @property
    def check(self) -> Callable | None:
        """The plausibility check of a candidate (``None``: ``validity`` off)."""
        if not self.validity:
            return None
        if self.max_volume_change is None:
            return candidate_validity
        return functools.partial(candidate_validity, max_volume_change=self.max_volume_change)


@dataclass(frozen=True)
class RunPlan:
    """One red-team run, as its settings say it is to run.

    Attributes:
        run_dir: the run's folder (a resume's own, else Hydra's output folder).
        resume: whether the run continues one in ``run_dir``.
        object: the object spec (a built-in name or a mesh file); object_scale: meters per mesh unit.
        cache_dir: GRT's cache (collision parts, ManiSkill actors).
        mesh: how the object's mesh is prepared.
        task, policy: the task and policy configs, plain and resolved (what sessions and workers take).
        selector, optimizer, evaluator, logger: the ``_target_`` nodes built at run time, plain.
        deformer: the deformation model and plausibility check.
        budget: the numbers of the search.
        score: the task's score spec; nominal_floor: the least S0 worth red-teaming (``None``: off).
        crash_margin: the least relative drop below S0 that makes a candidate a CrashShape.
        report_videos: CrashShapes filmed for ``report.html`` (``report.videos``).
        swap_check: the swap check of a ManiSkill task's copy against its stock env (``swap_check``,
            :mod:`grt.swapcheck`).
        choices: the config-group options of the run (``selector``: ``heuristic`` ...).
        config: the resolved config as a run folder and a logger keep it (a served policy's secret as given).
        record: the run's command line as ``run_config.yaml`` keeps it: ``overrides`` and ``choices``.
    """

    run_dir: Path
    resume: bool
    object: str
    object_scale: float
    cache_dir: str
    mesh: MeshSettings
    task: dict
    policy: dict
    selector: dict
    optimizer: dict
    evaluator: dict
    logger: dict
    deformer: DeformerPlan
    budget: Budget
    score: ScoreSpec
    nominal_floor: float | None
    crash_margin: float
    report_videos: int
    swap_check: SwapCheckSettings = field(default_factory=SwapCheckSettings)
    choices: dict = field(default_factory=dict)
    config: dict = field(default_factory=dict)
    record: dict = field(default_factory=dict)

    @staticmethod
    def task_settings(task: Mapping | None) -> tuple[ScoreSpec, float | None, float]:
        """``(score spec, nominal floor, crash margin)`` of a task config, each read in one place
        (:mod:`grt.scores`).

        Raises:
            ScoreConfigError: a bad ``task.ci``, ``task.nominal_floor`` or ``task.crash_margin``.
        """
        return ScoreSpec.from_task(task), nominal_floor(task), crash_margin(task)

    @property
    def object_name(self) -> str:
        """The object's short name (:func:`object_name`)."""
        return object_name(self.object)

    def smoothness_cap(self, mesh) -> tuple[float | None, str]:
        """The run's Smoothness-Score cap τ in meters (``budget.tau``, else ``budget.tau_rel`` x ``mesh``'s
        bounding-box diagonal; ``None``: none) and the sentence that says so."""
        import numpy as np

        return budget_tau(self.budget.tau, self.budget.tau_rel, float(np.linalg.norm(mesh.extents)))

    def racing(self) -> Racing | None:
        """The run's racing settings (``budget.racing``; ``None``: off, every candidate runs every trial)."""
        b = self.budget
        return Racing(b.race_rounds, b.race_alpha, b.top_k, self.crash_margin) if b.racing else None


def object_name(spec: str) -> str:
    """A short name for an object spec: the built-in name, or a file's stem."""
    text = str(spec)
    return Path(text).stem if ("/" in text or "." in text) else text


def object_folder(spec: str) -> str:
    """The folder name of an object spec in run folders' paths: a built-in's name (``mug``), a mesh file's
    name with its suffix (``mug.obj``; ``mug-file`` for a file without one), so the runs of a user's mesh
    named like a built-in never land beside the built-in's."""
    text = str(spec)
    if not ("/" in text or "." in text):
        return text
    name = Path(text).name or text.strip("/").replace("/", "_")
    return name if Path(name).suffix else f"{name}-file"


def dotted(config: Mapping, key: str, default=None):
    """The value at dotted ``key`` (``budget.videos``) of a plain config, or ``default`` where it is absent."""
    node = config
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return default
        node = node[part]
    return node
