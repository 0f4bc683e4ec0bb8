"""Dispatch ``python -m grt.bench NAME [args]`` to ``grt.bench.NAME.main(args)``."""

from __future__ import annotations

import importlib
import sys

BENCHMARKS = ("deform", "grasp", "insertion", "drawer")


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in BENCHMARKS:
        sys.exit(f"usage: python -m grt.bench {{{','.join(BENCHMARKS)}}} [options]  (--help for each)")
    importlib.import_module(f"grt.bench.{argv[0]}").main(argv[1:])


if __name__ == "__main__":
    main()
