"""``grt-objects`` (``python -m grt.objects [--export DIR]``): list the built-in objects (the task each is for, size,
faces), optionally export them."""

from __future__ import annotations

import time
from pathlib import Path

from grt.cli._common import AppParser
from grt.objects import get_object, list_objects, object_regions, object_task


def main(argv: list[str] | None = None) -> None:
    ap = AppParser("objects", description=__doc__)
    ap.add_argument("--export", metavar="DIR", help="write every object as DIR/<name>.obj (meters)")
    args = ap.parse_args(argv)
    print(f"{'name':14s} {'task':10s} {'size x y z (m)':24s} {'faces':>6s} {'build':>7s}  regions")
    for name in list_objects():
        t = time.perf_counter()
        mesh = get_object(name)
        dt = time.perf_counter() - t
        size = " ".join(f"{e:.3f}" for e in mesh.extents)
        print(f"{name:14s} {object_task(name):10s} {size:24s} {len(mesh.faces):6d} {dt * 1000:5.0f}ms  "
              f"{', '.join(object_regions(name))}")
        if args.export:
            out = Path(args.export)
            out.mkdir(parents=True, exist_ok=True)
            mesh.export(out / f"{name}.obj")
    print("task: the task each object is made for (python -m grt.run task=<task> object=<name>); any object can be "
          "grasped, the insertion and drawer tasks need their own objects")
    if args.export:
        print(f"exported {len(list_objects())} objects to {args.export}")


def cli() -> None:
    """``grt-objects``."""
    main()
