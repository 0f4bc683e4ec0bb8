"""The blue-team study as a plan: its settings (``python -m grt.blueteam``'s config), parsed and checked once.

The app (:mod:`grt.cli.blueteam`) makes a :class:`StudySpec` from its composed config with :meth:`StudySpec.of`
before torch or the simulator is imported; the study (:mod:`grt.blueteam.study`), the fine-tune and the guard
read the spec, never the config. A value the study cannot work with is one :class:`BlueTeamError` line here,
before the red-team run is even read. Light on purpose: nothing here imports torch or the simulator.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from grt.agreement import SwapCheckSettings
from grt.errors import UserError
from grt.plan import Rule, at_least


class BlueTeamError(UserError):
    """A red-team run that cannot be blue-teamed (no journal, no CrashShape, an untrainable policy), or a study
    setting it cannot work with."""


GUARDS = ("fisher", "tolerance")


def check_guard(guard: str) -> None:
    """Refuse an unknown ``blueteam.nominal_guard`` before any work."""
    if guard not in GUARDS:
        raise BlueTeamError(f"blueteam.nominal_guard={guard!r} is not a guard: fisher (refuse a checkpoint whose "
                            "nominal validation is significantly below the start) or tolerance (refuse one more "
                            "than blueteam.nominal_tolerance below it)")


def _number_in(low: float, high: float, closed_low: bool) -> Callable[[Any], bool]:
    def check(v) -> bool:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            return False
        return (low <= v < high) if closed_low else (low < v <= high)
    return check


#: What the checked settings of ``blueteam`` accept, in the order they are checked (one line for the first bad).
RULES: dict[str, Rule] = {
    **{key: at_least(1) for key in ("iterations", "top_k", "num_envs", "num_steps_per_env", "max_steps",
                                    "eval_trials", "val_trials", "val_interval", "val_patience")},
    "nominal_share": Rule("a number in [0, 1) (the fraction of training episodes on the nominal object; the rest "
                          "are on the CrashShapes)", _number_in(0.0, 1.0, closed_low=True)),
    "failing_below": Rule("a number in (0, 1] (a CrashShape scores below this fraction of S0)",
                          _number_in(0.0, 1.0, closed_low=False)),
}


@dataclass(frozen=True)
class Confirm:
    """``blueteam.confirm``: the ``candidates`` best validated checkpoints re-scored on ``trials`` fresh episodes
    each (0 candidates: the best validation is exported unconfirmed)."""

    candidates: int
    trials: int


@dataclass(frozen=True)
class Anchor:
    """``blueteam.anchor`` (:class:`grt.rl.anchor.NominalAnchor`): ``updates`` Adam steps per PPO iteration (0:
    off) toward the starting policy's actions, recorded for ``steps`` steps in ``envs`` environments with
    action noise ``noise``."""

    updates: int
    steps: int
    envs: int
    noise: float


@dataclass(frozen=True)
class HeldOut:
    """``blueteam.heldout``: up to ``candidates`` failing candidates not trained on, and ``nearby`` fresh
    deformations per CrashShape (its theta + N(0, ``sigma``), unit-cube units)."""

    candidates: int
    nearby: int
    sigma: float


@dataclass(frozen=True)
class StudySpec:
    """One blue-team study's settings (``conf/blueteam.yaml`` and ``conf/blueteam/default.yaml`` say what each
    means).

    Attributes:
        run: the red-team run folder.
        workers: simulator processes of the training environments.
        cache_dir: GRT's cache (collision parts).
        evaluator: the ``evaluator`` node (``_target_``, plain), built with :func:`grt.targets.build`.
        swap_check: the swap check of a ManiSkill task's run.
        crashshapes: ``top1``, ``topk``, ``all-failing`` or candidate names.
        val_trials_nominal: validation episodes of the nominal object (``val_trials`` when not given).
        algorithm: overrides of the checkpoint's own PPO settings.
        rered: re-red-team the fine-tuned policy.
        The other fields are ``blueteam.<name>``'s.
    """

    run: Path
    workers: int
    cache_dir: str
    evaluator: dict
    swap_check: SwapCheckSettings
    crashshapes: str | tuple[str, ...]
    top_k: int
    failing_below: float
    nominal_share: float
    iterations: int
    num_envs: int
    num_steps_per_env: int
    max_steps: int
    freeze_normalization: bool
    algorithm: dict
    eval_trials: int
    val_trials: int
    val_trials_nominal: int
    val_interval: int
    val_patience: int
    nominal_guard: str
    nominal_alpha: float
    nominal_tolerance: float
    confirm: Confirm
    anchor: Anchor
    heldout: HeldOut
    seed: int
    rered: bool

    @classmethod
    def of(cls, blueteam: Mapping, *, run, workers, cache_dir, evaluator: Mapping,
           swap_check: Mapping | None = None) -> StudySpec:
        """The spec of the app's config, plain: its ``blueteam`` section, ``run``, ``workers``,
        ``paths.cache_dir``, ``evaluator`` and ``swap_check`` (``None``: the defaults).

        Raises:
            BlueTeamError: a setting out of range (:data:`RULES`, ``nominal_guard``, ``confirm``), naming it and
                what it accepts.
            SwapCheckError: a bad ``swap_check`` value.
        """
        bt = blueteam
        _check(bt)
        mode = bt["crashshapes"]
        return cls(
            run=Path(run), workers=int(workers), cache_dir=str(cache_dir), evaluator=dict(evaluator),
            swap_check=SwapCheckSettings.from_config(swap_check),
            crashshapes=mode if isinstance(mode, str) else tuple(mode), top_k=int(bt["top_k"]),
            failing_below=float(bt["failing_below"]), nominal_share=float(bt["nominal_share"]),
            **{key: int(bt[key]) for key in ("iterations", "num_envs", "num_steps_per_env", "max_steps",
                                             "eval_trials", "val_trials", "val_interval", "val_patience", "seed")},
            freeze_normalization=bool(bt["freeze_normalization"]), algorithm=dict(bt["algorithm"]),
            val_trials_nominal=int(bt.get("val_trials_nominal") or bt["val_trials"]),
            nominal_guard=str(bt["nominal_guard"]), nominal_alpha=float(bt["nominal_alpha"]),
            nominal_tolerance=float(bt["nominal_tolerance"]),
            confirm=Confirm(int(bt["confirm"]["candidates"]), int(bt["confirm"]["trials"])),
            anchor=Anchor(**{k: int(bt["anchor"][k]) for k in ("updates", "steps", "envs")},
                          noise=float(bt["anchor"]["noise"])),
            heldout=HeldOut(int(bt["heldout"]["candidates"]), int(bt["heldout"]["nearby"]),
                            float(bt["heldout"]["sigma"])),
            rered=bool(bt["rered"]["enabled"]))


def _check(bt: Mapping) -> None:
    """Refuse settings that cannot work, before any simulation (the first bad one, in one line)."""
    check_guard(str(bt.get("nominal_guard")))
    for key, rule in RULES.items():
        if not rule.check(bt.get(key)):
            raise BlueTeamError(f"blueteam.{key}={bt.get(key)}: give {rule.accepts}")
    candidates, trials = bt["confirm"]["candidates"], bt["confirm"]["trials"]
    if int(candidates) < 0 or (int(candidates) > 0 and int(trials) < 1):
        raise BlueTeamError(f"blueteam.confirm: candidates={candidates}, trials={trials} cannot confirm: give "
                            "candidates >= 1 and trials >= 1, or candidates=0 to export the best validation "
                            "unconfirmed")
