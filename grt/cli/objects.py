"""``grt-objects`` (``python -m grt.objects [--export DIR]``): list the built-in objects (the task each is for, size,
faces), optionally export them."""

from __future__ import annotations

import time
from pathlib import Path

from grt.cli._common import AppParser, exit_on_user_error, write_output
from grt.errors import OutputError
from grt.objects import get_object, list_objects, object_regions, object_task


def check_export(folder: Path, overwrite: bool) -> None:
    """Make ``folder`` for ``--export`` before anything is printed or written, and refuse to replace files it
    holds under the objects' names unless ``overwrite``.

    Raises:
        OutputError: the folder cannot be made, or it holds such files (names them and the fix).
    """
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"--export {folder}: cannot make the folder ({exc.strerror or exc}); give a folder you "
                          "can write to") from None
    there = [f"{name}.obj" for name in list_objects() if (folder / f"{name}.obj").exists()]
    if there and not overwrite:
        shown = ", ".join(there[:4]) + (f" and {len(there) - 4} more" if len(there) > 4 else "")
        raise OutputError(f"--export {folder} already holds {shown}: give another folder, or --overwrite to "
                          "replace them")


def main(argv: list[str] | None = None) -> None:
    ap = AppParser("objects", description=__doc__)
    ap.add_argument("--export", metavar="DIR", help="write every object as DIR/<name>.obj (meters)")
    ap.add_argument("--overwrite", action="store_true", help="with --export: replace files of the same names")
    args = ap.parse_args(argv)
    with exit_on_user_error():
        _objects(args)


def _objects(args) -> None:
    if args.export:
        check_export(Path(args.export), args.overwrite)
    print(f"{'name':14s} {'task':10s} {'size x y z (m)':24s} {'faces':>6s} {'build':>7s}  regions")
    for name in list_objects():
        t = time.perf_counter()
        mesh = get_object(name)
        dt = time.perf_counter() - t
        size = " ".join(f"{e:.3f}" for e in mesh.extents)
        print(f"{name:14s} {object_task(name):10s} {size:24s} {len(mesh.faces):6d} {dt * 1000:5.0f}ms  "
              f"{', '.join(object_regions(name))}")
        if args.export:
            write_output(Path(args.export) / f"{name}.obj", mesh.export(file_type="obj"), flag="--export DIR")
    print("task: the task each object is made for (python -m grt.run task=<task> object=<name>); any object can be "
          "grasped, the insertion and drawer tasks need their own objects")
    if args.export:
        print(f"exported {len(list_objects())} objects to {args.export}")


def cli() -> None:
    """``grt-objects``."""
    main()
