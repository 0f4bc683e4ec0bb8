"""``grt-bench`` (``python -m grt.bench NAME [args]``): dispatch to ``grt.bench.NAME.main(args)``.

A mistake (unknown benchmark, object, mesh, policy or config override) is one ``error:`` line and exit
code 2; Ctrl-C ends a benchmark with one line and exit code 130.
"""

from __future__ import annotations

import importlib
import sys

from grt.cli._common import about_line, exit_on_user_error

BENCHMARKS = ("deform", "grasp", "insertion", "drawer", "meshes", "remote", "scale", "gpu", "racing")
USAGE = f"usage: python -m grt.bench {{{','.join(BENCHMARKS)}}} [options]  (--help for each)"


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(f"{about_line('bench')}\n\n{USAGE}" if argv else USAGE, file=sys.stdout if argv else sys.stderr)
        raise SystemExit(0 if argv else 2)
    if argv[0] not in BENCHMARKS:
        print(f"error: unknown benchmark {argv[0]!r}; choose one of {', '.join(BENCHMARKS)}", file=sys.stderr)
        raise SystemExit(2)
    with exit_on_user_error():
        importlib.import_module(f"grt.bench.{argv[0]}").main(argv[1:])


def cli() -> None:
    """``grt-bench``."""
    main()
