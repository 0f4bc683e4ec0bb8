"""``python -m grt.replay RUN [candidate=it3_c5|nominal] [seed=N] [video=out.mp4]``: re-run one trial of a run.

The candidate's mesh is rebuilt from the run folder (``nominal.obj``, ``handles.json``, the journal's
theta) and its trial re-run on the journal's episode seed in this process (:mod:`grt.rerun`); it prints
the outcome and failure mode beside the journal's and, as its last line, one JSON object with
``candidate``, ``seed``, ``outcome``, ``journal_outcome`` and ``match``. Without ``candidate``/``seed`` it
replays the rank-1 CrashShape's first failing trial. ``video=PATH.mp4`` films it from the task's render
camera (an existing file is replaced only with ``--overwrite``). The replay is recorded in ``RUN/replays.jsonl``. Exit code 0 when the outcome matches the journal's,
1 when it does not, 2 for a mistake in what was given (one ``error:`` line).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from grt.cli._common import AppParser, exit_on_user_error

KEYS = ("candidate", "seed", "video")


def _parse(items: list[str], overwrite: bool = False) -> dict:
    from grt.rerun import ReplayError

    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in KEYS:
            raise ReplayError(f"{item!r}: give key=value with key one of {', '.join(KEYS)} "
                              "(e.g. candidate=it3_c5 seed=123 video=out.mp4)")
        out[key] = value
    if "seed" in out:
        try:
            out["seed"] = int(out["seed"])
        except ValueError:
            raise ReplayError(f"seed={out['seed']!r}: an episode seed is an integer (the report lists them)") from None
    if ("candidate" in out) != ("seed" in out):
        raise ReplayError("give candidate= and seed= together, or neither (the rank-1 CrashShape's first failing trial)")
    if "video" in out and not out["video"].endswith(".mp4"):
        raise ReplayError(f"video={out['video']}: the video is an MP4 file; give a path ending in .mp4")
    if "video" in out and Path(out["video"]).exists() and not overwrite:
        raise ReplayError(f"video={out['video']} already exists; give another video=PATH.mp4, or --overwrite to "
                          "replace it")
    return out


def check_run(run: Path) -> None:
    """Refuse a folder with no journal: no run, or a run stopped before its first candidate (its command).

    Raises:
        ReplayError: names the folder and what to do.
    """
    from grt.rerun import ReplayError
    from grt.runfolder.record import is_run_folder, resume_command

    if (run / "journal.jsonl").is_file():
        return
    if is_run_folder(run):
        raise ReplayError(f"{run} is a run stopped before its first candidate was journaled: it has no trial to "
                          f"replay yet; continue it with {resume_command(run)}")
    raise ReplayError(f"{run} is not a GRT run folder (no journal.jsonl); give the folder python -m grt.run wrote")


def main(argv: list[str] | None = None) -> int:
    ap = AppParser("replay", description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a red-team run folder")
    ap.add_argument("options", nargs="*", help="candidate=it<t>_c<i>|nominal seed=<N> video=<out.mp4>")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing video= file")
    args = ap.parse_args(argv)
    with exit_on_user_error():
        from grt.rerun import RunReplayer, check_trial, first_failure, parse_candidate

        opts = _parse(args.options, args.overwrite)
        check_run(args.run)
        name, seed = (opts["candidate"], opts["seed"]) if "candidate" in opts else first_failure(args.run)
        it, c = parse_candidate(name)
        check_trial(args.run, it, c, seed)  # a wrong candidate or seed is refused before anything is built
        replayer = RunReplayer(args.run)
        try:
            print(f"replaying {name} on episode seed {seed} ({args.run})", flush=True)
            result = replayer.run(it, c, seed, video=Path(opts["video"]) if "video" in opts else None)
        finally:
            replayer.close()
        if replayer.notes:
            result["notes"] = replayer.notes
        print(f"outcome: {result['outcome']} (score {result['score']:g}); journal: {result['journal_outcome']} "
              f"(score {result['journal_score']:g}); {'match' if result['match'] else 'MISMATCH'}")
        if result.get("video"):
            print(f"video: {result['video']} ({result['frames']} frames)")
        with open(args.run / "replays.jsonl", "a", encoding="utf-8") as f:
            f.write(json.dumps(result) + "\n")
        print(f"recorded in {args.run / 'replays.jsonl'} (one line per replay: outcome, journal's outcome, video)")
        print(json.dumps({k: result[k] for k in ("candidate", "seed", "outcome", "journal_outcome", "match")}))
    return 0 if result["match"] else 1


def cli() -> None:
    """Console script ``grt-replay``."""
    sys.exit(main())
