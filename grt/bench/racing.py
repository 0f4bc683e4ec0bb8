"""``python -m grt.bench racing``: what racing saves, and what it risks.

``replay RUN_OR_JOURNAL ...`` (no simulation): applies the racing rule offline to the journals of runs made
without racing, where every candidate ran every trial in the run's seed order: for each candidate, the look at
which the rule would have stopped it (from its own first trials and the full-trial CrashShapes of the earlier
iterations), the trials that would have saved, and whether the candidate would have mattered (a CrashShape
that beats the earlier top-k): a stopped one that mattered is a loss. The search itself is replayed as it ran
(a racing run's search may differ: it is told a stopped candidate's mean over the trials it ran).

``run [OVERRIDES]``: the same red-team run twice in this process, racing off and on (``budget.racing=true``),
each in its own folder under ``--out``; prints trials, wall time and their ratios, and whether the racing
run found the same best score and Final Drop.

``rule``: the cost of computing the rule (:func:`grt.racing.look_level`, the main process's work while the
workers wait) against the reference computation (:func:`reference_look_level`: every hypergeometric
probability in exact integers, every attainable level's risk summed over all states), both in this process,
at growing trial counts; prints seconds, their ratio, and whether both give the same stop bounds (the
reference only up to ``--reference-up-to`` trials: it takes minutes at 1024).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from grt.errors import UserError
from grt.racing import Race, failures_needed, kth_best, look_level, looks
from grt.scores import is_crash


def _records(path: Path) -> tuple[list[dict], dict]:
    from grt.journal import Journal

    run = path if path.is_dir() else path.parent
    journal = Journal(run / "journal.jsonl" if path.is_dir() else path)
    if not journal.records:
        raise UserError(f"{path}: no journal records; give a run folder or its journal.jsonl")
    summary = json.loads((run / "summary.json").read_text()) if (run / "summary.json").exists() else {}
    return journal.records, summary


def replay(records: list[dict], rounds: int, alpha: float, top_k: int, margin: float) -> dict:
    """The racing rule applied to a full-trial journal's candidates; see the module docstring."""
    s0 = records[0]["score"]
    trials = len(records[0]["trials"])
    used = full = lost = mattered = stopped = 0
    for rec in records[1:]:
        if not rec.get("trials") or rec.get("race"):
            continue
        if len(rec["trials"]) != trials:
            raise UserError("the journal holds raced candidates: replay needs a run made without racing")
        race = Race(trials, rounds, alpha, s0, margin, kth_best(records, top_k, s0, margin, rec["iteration"]))
        outcome = [t["score"] for t in rec["trials"]]
        ran = trials
        for n in race.at:
            if any(t["mode"] == "sim_error" for t in rec["trials"][:n]):
                break
            if race.stop(outcome[:n]) is not None:
                ran = n
                break
        matters = is_crash(rec["score"], s0, margin) and (race.kth is None or rec["score"] < race.kth - 1e-12)
        used, full = used + ran, full + trials
        stopped += ran < trials
        mattered += matters
        lost += matters and ran < trials
    return {"trials": trials, "looks": list(looks(trials, rounds)), "candidates": len(records) - 1,
            "trials_full": full, "trials_raced": used, "ratio": used / full if full else float("nan"),
            "stopped": stopped, "mattered": mattered, "lost": lost}


def _replay_main(args) -> None:
    rows = []
    for path in args.runs:
        records, summary = _records(Path(path))
        margin = summary.get("crash_margin", 0.1)
        for alpha in args.alpha:
            row = replay(records, args.rounds, alpha, args.top_k, margin)
            rows.append({"run": str(path), "alpha": alpha, **row})
            print(f"{path}: alpha {alpha:g}, {row['candidates']} candidates x {row['trials']} trials, looks at "
                  f"{row['looks']}: {row['trials_raced']}/{row['trials_full']} trials ({row['ratio']:.0%}), "
                  f"{row['stopped']} stopped, {row['lost']} of {row['mattered']} that mattered stopped", flush=True)
    if len(rows) > 1:
        for alpha in args.alpha:
            sub = [r for r in rows if r["alpha"] == alpha]
            raced, whole = sum(r["trials_raced"] for r in sub), sum(r["trials_full"] for r in sub)
            print(f"all {len(sub)} journals, alpha {alpha:g}: {raced}/{whole} trials ({raced / whole:.0%}), "
                  f"{sum(r['lost'] for r in sub)} of {sum(r['mattered'] for r in sub)} that mattered stopped")
    print(json.dumps(rows))


def _timed_run(overrides: list[str], out: Path) -> tuple[dict, float]:
    """One red-team run of ``grt.run``'s config with ``overrides`` into ``out``; its summary and seconds."""
    from hydra import compose, initialize_config_dir

    from grt.config import validate
    from grt.runner import run

    conf = Path(__file__).resolve().parents[2] / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        cfg = compose(config_name="run", overrides=[*overrides, f"paths.output_dir={out}", "budget.videos=0"])
    validate(cfg)
    start = time.perf_counter()
    summary = run(cfg)
    return summary, time.perf_counter() - start


def _compare(args) -> None:
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise UserError(f"--out {out} is not empty: give a new folder")
    off, t_off = _timed_run(args.overrides, out / "off")
    on, t_on = _timed_run([*args.overrides, "budget.racing=true"], out / "on")
    print(f"racing off: {off['trials_used']} trials, {t_off:.0f} s; best {off['best_score']:.3f}, Final Drop "
          f"{off['final_drop']:.1%}")
    print(f"racing on:  {on['trials_used']} trials, {t_on:.0f} s; best {on['best_score']:.3f}, Final Drop "
          f"{on['final_drop']:.1%}; stopped {on['racing']['stopped']} of {on['racing']['stopped'] + on['racing']['full']}")
    print(f"ratio on/off: trials {on['trials_used'] / off['trials_used']:.2f}, wall {t_on / t_off:.2f} (same machine, "
          "same process, one after the other)")
    print(json.dumps({"off": {"trials": off["trials_used"], "wall_s": t_off, "final_drop": off["final_drop"]},
                      "on": {"trials": on["trials_used"], "wall_s": t_on, "final_drop": on["final_drop"]}}))


def _pmf(total: int, bad: int, n: int) -> list[float]:
    whole = math.comb(total, n)
    return [math.comb(bad, f) * math.comb(total - bad, n - f) / whole for f in range(n + 1)]


def _cdf(total: int, bad: int, n: int, f: int) -> float:
    return sum(_pmf(total, bad, n)[: f + 1])


def _reference_stops(total: int, bad: int, at: tuple[int, ...], level: float) -> list[int]:
    out = []
    for n in at:
        most = -1
        for f in range(n + 1):
            if f + (total - n) < bad or _cdf(total, bad, n, f) <= level + 1e-15:
                most = f
            else:
                break
        out.append(most)
    return out


def reference_risk(total: int, bad: int, at: tuple[int, ...], bounds: list[int]) -> float:
    """The exact risk of :func:`grt.racing._risk` computed over every state, each step's probabilities in exact
    integers."""
    alive, seen, stopped = {0: 1.0}, 0, 0.0
    for n, most in zip(at, bounds, strict=True):
        nxt: dict[int, float] = {}
        for f, p in alive.items():
            for g, q in enumerate(_pmf(total - seen, bad - f, n - seen)):
                if q:
                    nxt[f + g] = nxt.get(f + g, 0.0) + p * q
        stopped += sum(p for f, p in nxt.items() if f <= most)
        alive, seen = {f: p for f, p in nxt.items() if f > most}, n
    return stopped


def reference_look_level(total: int, bad: int, at: tuple[int, ...], alpha: float) -> tuple[int, ...]:
    """:func:`grt.racing.look_level` by its definition, the straightforward way: the reference its results and
    its speed are measured against (``rule``)."""
    levels = [c for c in sorted({_cdf(total, bad, n, f) for n in at for f in range(n + 1)} | {0.0})
              if c <= alpha + 1e-15]
    best = _reference_stops(total, bad, at, 0.0)
    lo, hi = 0, len(levels) - 1
    while lo <= hi:
        mid = (lo + hi) // 2
        bounds = _reference_stops(total, bad, at, levels[mid])
        if reference_risk(total, bad, at, bounds) <= alpha + 1e-12:
            best, lo = bounds, mid + 1
        else:
            hi = mid - 1
    return tuple(best)


def _rule_main(args) -> None:
    rows = []
    for trials in args.trials:
        at = looks(trials, args.rounds)
        bad = failures_needed(trials, args.s0, args.margin, None)
        if bad is None:
            raise UserError(f"--s0 {args.s0} --margin {args.margin}: no failure count makes a CrashShape")
        look_level.cache_clear()
        start = time.perf_counter()
        bounds = look_level(trials, bad, at, args.alpha)
        fast = time.perf_counter() - start
        row = {"trials": trials, "needed": bad, "bounds": list(bounds), "seconds": fast}
        line = f"{trials:>5} trials ({bad} failures needed): {fast * 1e3:8.1f} ms"
        if trials <= args.reference_up_to:
            start = time.perf_counter()
            reference = reference_look_level(trials, bad, at, args.alpha)
            slow = time.perf_counter() - start
            row.update(reference_s=slow, ratio=slow / fast, same=reference == bounds)
            line += f"; reference {slow:8.2f} s: {slow / fast:8.0f}x faster, same bounds: {reference == bounds}"
        print(line, flush=True)
        rows.append(row)
    print(json.dumps(rows))


def main(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(prog="python -m grt.bench racing", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="mode", required=True)
    rep = sub.add_parser("replay", help="apply the rule offline to full-trial journals")
    rep.add_argument("runs", nargs="+", help="run folders or journal.jsonl files made without racing")
    rep.add_argument("--rounds", type=int, default=8)
    rep.add_argument("--alpha", type=float, nargs="+", default=[0.0, 0.05])
    rep.add_argument("--top-k", type=int, default=3)
    run = sub.add_parser("run", help="one run with racing off and on, same process")
    run.add_argument("overrides", nargs="*", help="grt.run overrides (default: the demo)")
    run.add_argument("--out", default="outputs/bench_racing")
    rule = sub.add_parser("rule", help="the cost of the racing rule against its reference computation")
    rule.add_argument("--trials", type=int, nargs="+", default=[64, 128, 256, 512, 1024, 4096])
    rule.add_argument("--rounds", type=int, default=8)
    rule.add_argument("--alpha", type=float, default=0.05)
    rule.add_argument("--s0", type=float, default=0.9, help="nominal success rate")
    rule.add_argument("--margin", type=float, default=0.1, help="task.crash_margin")
    rule.add_argument("--reference-up-to", type=int, default=256,
                      help="time the reference only up to this many trials (it takes minutes at 1024)")
    args = parser.parse_args(argv)
    {"replay": _replay_main, "run": _compare, "rule": _rule_main}[args.mode](args)
