"""How a run's figures you can trust read, in one place: the confirmed drop (first), Final Drop beside its noise
floor, and the swap check of a ManiSkill task. The printed table (:func:`grt.outputs.print_summary`),
``python -m grt.report`` tables and ``report.html`` all word them here, from ``summary.json`` alone.
"""

from __future__ import annotations

import math

from grt.noise_floor import noise_floor


def pct(v, digits: int = 1) -> str:
    """A fraction as a percentage without the sign (``0.625`` -> ``62.5``); ``-`` for None or NaN."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return f"{100 * v:.{digits}f}"


def confirmed_cell(summary: dict, unit: str = "") -> str:
    """``100.0 [88.7, 99.9] p=2e-09 (32 fresh)``: the rank-1 CrashShape's drop on fresh episodes (%, ``unit``
    after the drop: ``%`` on a console), its paired 95% interval and Holm p-value; why there is none otherwise
    (``off``, ``no CrashShape``)."""
    conf = summary.get("confirm")
    if not conf:
        if summary.get("crashshape_found") is False:
            return "no CrashShape"
        return "off (budget.confirm_trials=0)" if summary.get("confirmed_final_drop") is None else \
            pct(summary["confirmed_final_drop"])
    ci = conf.get("confirmed_drop_ci95") or (conf["shapes"][0].get("drop_ci95") if conf.get("shapes") else None)
    p = conf.get("confirmed_p", conf["shapes"][0]["p_holm"] if conf.get("shapes") else None)
    cell = pct(conf.get("confirmed_final_drop")) + unit
    if ci:
        cell += f" [{pct(ci[0])}, {pct(ci[1])}]"
    if p is not None:
        cell += f" p={p:.2g}"
    return cell + f" ({conf['trials']} fresh)"


def confirmed_verdict(summary: dict) -> str:
    """One sentence: how many of the top CrashShapes' drops held on fresh episodes, at which level."""
    conf = summary.get("confirm")
    if not conf:
        return ""
    return (f"{conf['confirmed']}/{len(conf['shapes'])} drops confirmed at α = {conf['alpha']} "
            f"({conf.get('test', 'paired test')})")


def floor_of(summary: dict) -> dict | None:
    """A run's noise floor: the one its ``summary.json`` records, or, for a success-rate run from before the
    floor was recorded, the exact floor from the summary's own counts (S0 x trials successes of the nominal,
    the candidates simulated: evaluations - 1 - implausible). ``None`` when neither can be had (a continuous
    score without its per-trial values)."""
    floor = summary.get("noise_floor")
    if floor:
        return floor if floor.get("mean") is not None and not math.isnan(floor["mean"]) else None
    s0, trials, evals = summary.get("s0"), summary.get("trials"), summary.get("evaluations")
    if summary.get("score_unit") or s0 is None or not trials or not evals:
        return None
    k = s0 * trials
    if abs(k - round(k)) > 1e-6:
        return None
    candidates = evals - 1 - int(summary.get("invalid_candidates") or 0)
    found = noise_floor([1.0] * round(k) + [0.0] * (int(trials) - round(k)), candidates, int(trials),
                        summary.get("final_drop"))
    return found if not math.isnan(found["mean"]) else None


def floor_cell(summary: dict, unit: str = "") -> str:
    """``62.5 (floor 25.1, 95% 62.5)``: Final Drop (%) beside the mean and 95th percentile of the Final Drop the
    same search would show if no deformation mattered (:mod:`grt.noise_floor`); summaries from before the
    floor: Final Drop alone."""
    cell = pct(summary.get("final_drop")) + unit
    floor = floor_of(summary)
    if floor:
        cell += f" (floor {pct(floor['mean'])}{unit}, 95% {pct(floor['q95'])}{unit})"
    return cell


def floor_sentence(summary: dict) -> str:
    """What the floor says about this run's Final Drop, in one line under 200 characters (empty without a floor)."""
    floor = floor_of(summary)
    if not floor:
        return ""
    fd, p = summary.get("final_drop"), floor.get("p_value")
    head = (f"noise floor of Final Drop: {pct(floor['mean'])}% (95th percentile {pct(floor['q95'])}%) for "
            f"{floor['candidates']} candidates x {floor['trials']} trials at this S0")
    if not fd:
        return head + "; this search found no drop"
    where = ("below the floor: luck alone gives as much" if fd <= floor["mean"] else
             "within the floor's 95%: luck gives it in over 1 search in 20" if fd <= floor["q95"] else
             "above the floor's 95th percentile")
    return head + (f"; P(null >= {pct(fd)}%) = {p:.2g}" if p is not None else "") + f": {where}"


def swap_line(summary: dict) -> str:
    """The swap check in one line (empty for a summary without one)."""
    check = summary.get("swap_check")
    if not check:
        return ""
    if check.get("stock") is None:
        return f"swap check: {check.get('note', 'no stock env')}"
    s, w = check["stock"], check["swap"]
    verdict = ("passed" if check["passed"] else
               "FAILED, accepted with swap_check.accept=true" if check.get("accepted") else "FAILED")
    cached = " (cached)" if check.get("cached") else ""
    return (f"swap check{cached}: stock {s['success_rate']:.3f} vs nominal swap {w['success_rate']:.3f} success on "
            f"the same {len(check['seeds'])} seeds, agreement {check['agreement']:.3f} (min {check['min_agreement']:g}), "
            f"McNemar p = {check['mcnemar_p']:.2g}: {verdict}")
