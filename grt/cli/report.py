"""``python -m grt.report PATH``: the paper's columns for a run, a multirun or an ``experiments/`` folder.

``--csv OUT.csv`` also writes the per-run rows; ``--markdown`` prints a folder's record (its run table and
its blue-team ``table3*.json`` tables), ``--records`` adds the commit that wrote each summary, and
``--html`` writes ``report.html`` (one self-contained page: a run folder's, or a sweep's linking each run's
page), ``--search-plot OUT.png`` draws the Final Drop against simulator trials per search method,
``--margins-plot OUT.png`` draws each run's margins (random, adversarial, smallest shrunk CrashShape) with
``--small FILE.json`` (``{object: mm}``, what the paper calls small) as bands,
``--update-readmes`` rewrites the generated table blocks of every ``README.md`` under PATH
(``python -m grt.report experiments --update-readmes``). An existing ``--csv``, ``--search-plot`` or
``--margins-plot`` file is replaced only with ``--overwrite``. A mistake (no such folder, no or a broken
``summary.json``, a ``--csv`` path that exists or cannot be written) is one ``error:`` line and exit code 2; a run
stopped before its end is one line naming the command that finishes it (as ``--html`` says on its page).
"""

from __future__ import annotations

from pathlib import Path

from grt.cli._common import AppParser, exit_on_user_error, write_output
from grt.errors import check_output_file
from grt.report.tables import (
    ReportError,
    aggregate,
    collect,
    csv_text,
    markdown,
    render,
    unfinished,
    update_readmes,
)
from grt.runfolder.record import is_run_folder, resume_command


def _margins_plot(args) -> None:
    """``--margins-plot``: the margins of the runs under ``args.path`` (and the bands of ``--small``)."""
    import json

    from grt.report.margins import plot_margins

    check_output_file(args.margins_plot, (".png",), "--margins-plot", overwrite=args.overwrite)
    try:
        small = json.loads(args.small.read_text()) if args.small else None
    except (OSError, ValueError) as exc:
        raise ReportError(f"--small {args.small}: cannot read it as JSON ({exc}); give {{object: mm}}") from None
    if small is not None and not (isinstance(small, dict) and all(isinstance(v, int | float) for v in small.values())):
        raise ReportError(f"--small {args.small}: give a JSON object of sizes in mm, e.g. {{\"mug\": 2.2}}")
    try:
        print(f"wrote {plot_margins(collect(args.path)[0], args.margins_plot, small)}")
    except ValueError as exc:
        raise ReportError(f"{args.path}: {exc}") from None


def main(argv: list[str] | None = None) -> None:
    ap = AppParser("report", description=__doc__.splitlines()[0])
    ap.add_argument("path", type=Path, help="a run folder, a multirun folder or an experiments/ folder")
    ap.add_argument("--csv", type=Path, help="also write the per-run rows as CSV (into an existing folder)")
    ap.add_argument("--markdown", action="store_true",
                    help="print the folder's record: run table and blue-team (table3*.json) tables")
    ap.add_argument("--records", action="store_true", help="with --markdown: the commit of every summary")
    ap.add_argument("--html", action="store_true",
                    help="write report.html: a run's page (3D CrashShapes, failure modes, videos) or a sweep's")
    ap.add_argument("--search-plot", type=Path, metavar="OUT.png",
                    help="write the degradation curve against simulator trials used, per search method")
    ap.add_argument("--margins-plot", type=Path, metavar="OUT.png",
                    help="write each run's margins in mm (runs with a robustness profile)")
    ap.add_argument("--small", type=Path, metavar="FILE.json",
                    help="with --margins-plot: {object: mm} drawn as bands (e.g. the paper's reach)")
    ap.add_argument("--update-readmes", action="store_true",
                    help="rewrite the <!-- grt.report ... --> blocks of every README.md under PATH")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --csv, --search-plot or --margins-plot file")
    args = ap.parse_args(argv)
    with exit_on_user_error(ReportError):
        if args.html:
            from grt.report.html import write_report

            for out in write_report(args.path):
                print(f"wrote {out}")
            return
        if args.search_plot:
            from grt.report.search import plot

            check_output_file(args.search_plot, (".png",), "--search-plot", overwrite=args.overwrite)
            try:
                print(f"wrote {plot(collect(args.path)[0], args.search_plot)}")
            except ValueError as exc:
                raise ReportError(f"{args.path}: {exc}") from None
            return
        if args.margins_plot:
            _margins_plot(args)
            return
        if args.update_readmes:
            changed = update_readmes(args.path)
            print("\n".join(f"updated {p}" for p in changed) or f"every README.md under {args.path} is up to date")
            return
        if args.csv:
            check_output_file(args.csv, (".csv",), "--csv", overwrite=args.overwrite)  # before reading anything
        if args.markdown or args.records:
            print(render(args.path, records=args.records))
            rows = collect(args.path)[0] if args.csv else []
        else:
            rows, failed = collect(args.path)
            waiting = unfinished(args.path)  # a sweep's jobs that never wrote summary.json
            if not rows and not failed and not waiting:
                raise ReportError(stopped_run(args.path) or f"no summary.json (or summary_<name>.json) under "
                                  f"{args.path}: is it a finished GRT run folder?")
            print(markdown(rows, aggregate(rows), failed, waiting))
        if args.csv:
            write_output(args.csv, csv_text(rows), "--csv PATH")
            print(f"\nwrote {args.csv}")


def stopped_run(path: Path) -> str | None:
    """What to say of a red-team run folder without ``summary.json`` (stopped before its end): how far it got
    and the command that finishes it, as ``--html`` says; ``None`` for any other folder."""
    if not is_run_folder(path) or (path / "summary.json").exists():
        return None
    journal = path / "journal.jsonl"
    done = journal.read_bytes().count(b"\n") if journal.is_file() else 0
    return (f"{path} is a run that has not finished (no summary.json; {done} candidate(s) in its journal): finish "
            f"it with {resume_command(path)}, then report on it (--html shows what it has so far)")


def cli() -> None:
    """Console script ``grt-report``."""
    main()
