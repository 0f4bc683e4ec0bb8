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
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from grt.errors import UserError
from grt.racing import Race, kth_best, looks
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
    args = parser.parse_args(argv)
    (_replay_main if args.mode == "replay" else _compare)(args)
