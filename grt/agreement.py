"""Does GRT's copy of a ManiSkill task behave as the stock task does? The statistics of the swap check.

GRT replaces a stock env's actor by the nominal mesh's convex parts. The swap check runs the policy on the
same episode seeds with the stock actor and with the nominal swap, and compares the two seed by seed:

- **agreement**: the fraction of seeds whose outcome (the failure mode, ``success`` included) is the same;
- **the test of the difference**: the exact two-sided McNemar test of equal success rates on the
  discordant seeds (one run succeeds, the other does not), ``p = min(1, 2 P(Bin(b + c, 1/2) <= min(b, c)))``.

The verdict is the agreement against :attr:`SwapCheckSettings.min_agreement` (0.75 by default, chosen from the
measured swaps below; docs/reading-results.md says how). Seeds lost to a simulator error on either side count
as disagreeing: a copy that cannot run the episode is not the stock task.

Measured (ManiSkill's motion planners, stock vs nominal swap): four box tasks 1.000 (32 seeds each),
PlugCharger (three boxes) 0.85 (20 seeds), LiftPegUpright 0.9 (10); a round actor 0.375 and a two-box
compound tool 0.438 (16 each). 0.75 passes every box task and refuses both bad copies. With the 8 seeds of
``budget=quick`` a copy as faithful as PlugCharger's (true agreement 0.85) is refused in 11% of runs and one
as unfaithful as the compound tool's (0.44) passes in 8%; with 16 seeds 8% and 1%, with 32 seeds 4% and 0.04%
(binomial counts of disagreeing seeds; :func:`error_rates`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from grt.errors import UserError

#: the default least per-seed agreement (see the module docstring for how it was chosen)
MIN_AGREEMENT = 0.75
TEST = "exact two-sided McNemar test of equal success rates on the discordant seeds"


class SwapCheckError(UserError):
    """The swap check refused a run, or a swap-check setting cannot be used; one line with the figures and the
    ways on."""


@dataclass(frozen=True)
class SwapCheckSettings:
    """The ``swap_check`` section of ``grt.run``, ``grt.evaluate`` and ``grt.blueteam``.

    Attributes:
        min_agreement: the least per-seed agreement of stock and swap that lets a run go on (0-1).
        accept: go on with a swap that disagrees (named in the message that stops the run; the summary
            records it as accepted). Refused for a task without a stock env: there is nothing to accept.
        enabled: ``false`` skips the check (the summary says it was skipped).
    """

    min_agreement: float = MIN_AGREEMENT
    accept: bool = False
    enabled: bool = True

    @classmethod
    def from_config(cls, node) -> SwapCheckSettings:
        """The settings of a config section (a dict, a DictConfig or ``None``: the defaults).

        Raises:
            SwapCheckError: a value out of range or of the wrong type, naming the key.
        """
        node = node if node is not None else {}
        unknown = sorted(set(node) - {"min_agreement", "accept", "enabled"})
        if unknown:
            raise SwapCheckError(f"swap_check.{unknown[0]} is not a swap-check setting; its keys are min_agreement, "
                                 "accept, enabled")
        value = node.get("min_agreement", MIN_AGREEMENT)
        if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
            raise SwapCheckError(f"swap_check.min_agreement={value!r}: give a number in [0, 1] (the least fraction "
                                 f"of seeds on which stock and swap end alike; default {MIN_AGREEMENT})")
        for key in ("accept", "enabled"):
            if not isinstance(node.get(key, key == "enabled"), bool):
                raise SwapCheckError(f"swap_check.{key}={node.get(key)!r}: give true or false")
        return cls(float(value), bool(node.get("accept", False)), bool(node.get("enabled", True)))


def mcnemar_p(first: Sequence[bool], second: Sequence[bool]) -> float:
    """Exact two-sided McNemar p-value that two paired success sequences have equal success rates.

    Args:
        first, second: ``(n,)`` success per seed, paired by position.

    Returns:
        p in (0, 1]; 1.0 without discordant pairs.
    """
    b = sum(1 for x, y in zip(first, second, strict=True) if x and not y)
    c = sum(1 for x, y in zip(first, second, strict=True) if y and not x)
    n = b + c
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(b, c) + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


def compare(stock_modes: Sequence[str], swap_modes: Sequence[str], seeds: Sequence[int],
            settings: SwapCheckSettings) -> dict:
    """The swap check's record from the two runs' outcome modes on the same seeds.

    Returns:
        ``{"seeds", "stock": {"success_rate", "modes"}, "swap": {...}, "agree", "agreement", "mcnemar_p",
        "test", "min_agreement", "passed", "accepted"}``; ``accepted`` is true only for a check that failed
        and ``settings.accept`` lets through.
    """
    if not (len(stock_modes) == len(swap_modes) == len(seeds)) or not seeds:
        raise ValueError("the stock run, the swap run and the seeds must have the same length (>= 1)")
    agree = [a == b and a != "sim_error" for a, b in zip(stock_modes, swap_modes, strict=True)]
    ok_stock = [m == "success" for m in stock_modes]
    ok_swap = [m == "success" for m in swap_modes]
    agreement = sum(agree) / len(agree)
    passed = agreement >= settings.min_agreement - 1e-12
    return {"seeds": [int(s) for s in seeds],
            "stock": {"success_rate": sum(ok_stock) / len(seeds), "modes": list(stock_modes)},
            "swap": {"success_rate": sum(ok_swap) / len(seeds), "modes": list(swap_modes)},
            "agree": agree, "agreement": agreement, "mcnemar_p": mcnemar_p(ok_stock, ok_swap), "test": TEST,
            "min_agreement": settings.min_agreement, "passed": passed, "accepted": bool(not passed and settings.accept)}


def refusal(task: str, record: dict) -> str:
    """The one line that stops a run whose swap disagrees: both figures and the ways on."""
    n, s, w = len(record["seeds"]), record["stock"], record["swap"]
    return (f"swap check: task={task}: the stock env succeeds on {round(s['success_rate'] * n)}/{n} seeds and GRT's "
            f"nominal swap on {round(w['success_rate'] * n)}/{n} of the same seeds; per-seed agreement "
            f"{record['agreement']:.3f} < swap_check.min_agreement={record['min_agreement']:g} (McNemar p = "
            f"{record['mcnemar_p']:.2g}), so a drop measured on this copy is not the stock task's. Fix the task "
            "YAML (actor, refresh, failure flags), or the actor's representation (python -m grt.calibrate "
            f"task={task} shows both runs seed by seed; max_hull_vertices), or accept it knowingly with "
            "swap_check.accept=true (recorded in summary.json)")


def error_rates(seeds: int, min_agreement: float = MIN_AGREEMENT, good: float = 0.85,
                bad: float = 0.44) -> tuple[float, float]:
    """``(P(refuse | true agreement good), P(pass | true agreement bad))`` with ``seeds`` independent seeds."""
    most = math.floor((1.0 - min_agreement) * seeds + 1e-9)  # disagreeing seeds that still pass

    def at_most(k: int, q: float) -> float:
        return sum(math.comb(seeds, i) * q**i * (1 - q) ** (seeds - i) for i in range(k + 1))

    return 1.0 - at_most(most, 1.0 - good), at_most(most, 1.0 - bad)
