"""The bottom of GRT's error path: the base of every user error, and the one Ctrl-C exit code.

Errors in what the user gave (object, mesh, journal, checkpoint, plug, VLM, score or budget settings, an
output path) subclass :class:`UserError` where they are defined and carry a message that names the problem
and the fix. The command-line apps (:mod:`grt.cli._common`) catch the base and print that message as one
``error:`` line with exit code 2, so the error path needs no registry of the domain errors; nothing here
imports another GRT module.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

INTERRUPTED = 130  # the shell's code for a process ended by SIGINT (128 + 2)
TERMINATED = 143  # and by SIGTERM (128 + 15), how schedulers and `timeout` stop a job


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread by the command-line apps' handler: a job a scheduler or ``timeout``
    stops ends as one stopped with Ctrl-C does (every ``except KeyboardInterrupt`` applies), exit code 143."""


class UserError(ValueError):
    """Base of every error in what the user gave (object, mesh, config, checkpoint, plug, VLM, output path):
    its message names the problem and the fix, and the command-line apps print it as one line, exit code 2.
    Domain errors subclass it where they are defined, so the error path needs no registry of them."""


class OutputError(UserError):
    """An output the tool cannot write (unsupported format, missing or read-only folder)."""


def check_output_file(path: str | Path, suffixes: Iterable[str] | None = None, flag: str = "--out",
                      overwrite: bool | None = None) -> Path:
    """Refuse an output file before any work: an unsupported extension, or a folder that does not exist; with
    ``overwrite=False``, a file that exists too (the user's file is replaced only when they ask: ``--overwrite``).

    Raises:
        OutputError: names the path, the problem and the fix.
    """
    path = Path(path)
    suffixes = tuple(suffixes or ())
    if path.is_dir():
        raise OutputError(f"{flag} {path}: that is a folder; give a file name in it ({flag} {path / 'NAME'})")
    if suffixes and path.suffix.lower() not in suffixes:
        given = f"unsupported format {path.suffix!r}" if path.suffix else "no file extension"
        raise OutputError(f"{flag} {path}: {given}; "
                          f"end the name with one of {', '.join(suffixes)}")
    folder = path.parent
    if not folder.exists():
        raise OutputError(f"{flag} {path}: the folder {folder} does not exist; create it (mkdir -p {folder}) "
                          f"or give another {flag}")
    if not folder.is_dir():
        raise OutputError(f"{flag} {path}: {folder} is a file, not a folder; give another {flag}")
    if overwrite is False and path.exists():
        given = f"{flag}{path}" if flag.endswith("=") else f"{flag} {path}"
        raise OutputError(f"{given} already exists; give another {flag.rstrip('=')}, or --overwrite to replace it")
    return path
