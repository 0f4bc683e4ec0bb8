"""One error path for GRT's command-line tools: a user's mistake is one line and exit code 2.

Errors in what the user gave (object, mesh, journal, checkpoint, plug, VLM, score or budget settings, an
output path) carry a message that names the problem and the fix; :func:`exit_on_user_error` prints it
without a traceback, and prints one line with exit code 130 for Ctrl-C. Mistakes Hydra finds while it
composes the config (an unknown key or option, a value of the wrong type), before the app runs, are
turned into the same one line by :func:`run_cli`, the ``__main__`` line of each Hydra app.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

log = logging.getLogger("grt")

INTERRUPTED = 130  # the shell's code for a process ended by SIGINT (128 + 2)
_NOISE = ("full_key:", "object_type=", "reference_type=", "See https://hydra.cc", "Config search path:")


class UserError(ValueError):
    """Base of every error in what the user gave (object, mesh, config, checkpoint, plug, VLM, output path):
    its message names the problem and the fix, and the command-line apps print it as one line, exit code 2.
    Domain errors subclass it where they are defined, so the error path needs no registry of them."""


class OutputError(UserError):
    """An output the tool cannot write (unsupported format, missing or read-only folder)."""


def user_errors() -> tuple[type[BaseException], ...]:
    """The exception types that mean "the input is wrong" (imported lazily: no simulator import)."""
    from grt.blueteam.core import BlueTeamError
    from grt.config import ConfigError
    from grt.evaluators.collision import CollisionError
    from grt.geometry.mesh import MeshError
    from grt.journal import JournalError
    from grt.objects import UnknownObjectError
    from grt.policies.cgn_net import CGNWeightsError
    from grt.policies.rsl_rl import CheckpointError
    from grt.scores import NominalFloorError, ScoreConfigError
    from grt.selectors.client import VLMError
    from grt.tasks.base import TaskInputError

    return (MeshError, UnknownObjectError, JournalError, VLMError, CollisionError, CheckpointError, TaskInputError,
            CGNWeightsError,
            BlueTeamError, ScoreConfigError, NominalFloorError, ConfigError, OutputError)


def find_user_error(exc: BaseException, also: tuple[type[BaseException], ...] = ()) -> BaseException | None:
    """The user error behind ``exc`` (Hydra wraps errors raised while instantiating), or ``None``.

    ``also``: more types to count as user errors (a CLI's own, defined in a module run as ``__main__``).
    """
    kinds = user_errors() + tuple(also)
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, kinds):
            return exc
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


@contextlib.contextmanager
def exit_on_user_error(*also: type[BaseException]):
    """Turn a user error (or one of the types ``also``) into ``error: <message>`` on stderr and exit code 2,
    Ctrl-C into one line and exit code 130."""
    try:
        yield
    except KeyboardInterrupt:
        print("interrupted (Ctrl-C)", file=sys.stderr)
        raise SystemExit(INTERRUPTED) from None
    except Exception as exc:
        found = find_user_error(exc, also) or _compose_error(exc)
        if found is None:
            raise
        print(f"error: {found}", file=sys.stderr)
        raise SystemExit(2) from None


def run_cli(main: Callable[[], object]) -> None:
    """Call a ``@hydra.main`` app so that every user mistake is one ``error:`` line and exit code 2.

    Covers what happens before the app's own code runs: Hydra's composition errors (unknown key or
    option, wrong type, bad override syntax) and an output folder it cannot create or write. Other
    errors keep their traceback (exit code 1). ``HYDRA_FULL_ERROR=1`` set by the user is honoured.
    Use: ``if __name__ == "__main__": run_cli(main)``.
    """
    previous = os.environ.get("HYDRA_FULL_ERROR")
    if previous == "1":
        with exit_on_user_error():
            main()
        return
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra re-raises what it would print (several lines, exit code 1)
    try:
        with exit_on_user_error():
            try:
                main()
            except OSError as exc:
                found = _setup_error(exc)
                if found is None:
                    raise
                raise found from exc
    finally:
        if previous is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = previous


def one_line(text: str) -> str:
    """Hydra's and OmegaConf's several-line messages as one line (lists joined, object dumps dropped)."""
    parts: list[str] = []
    for raw in str(text).split("Config search path:")[0].splitlines():
        line = raw.strip()
        if not line or line.startswith(_NOISE):
            continue
        if raw.startswith("\t") and parts:  # an item of a list ("Available options in 'selector':")
            parts[-1] += (" " if parts[-1].endswith(":") else ", ") + line
        else:
            parts.append(line.rstrip("."))
    return "; ".join(parts)


def _compose_error(exc: BaseException) -> str | None:
    """One line for a mistake Hydra finds while composing a config, or ``None`` for other errors."""
    from hydra.errors import ConfigCompositionException, OverrideParseException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

    from grt.config import BudgetSchema, budget_hint, unknown_budget_key

    if not isinstance(exc, (ConfigCompositionException, OverrideParseException)):
        return None
    cause = exc.__cause__
    key = str(getattr(cause, "full_key", "") or "")
    in_budget = getattr(cause, "object_type", None) is BudgetSchema
    if isinstance(cause, (ConfigKeyError, ConfigAttributeError)) and in_budget:  # Hydra would hint at '+'
        return unknown_budget_key(key.split(".", 1)[1])
    text = one_line(str(exc))
    if isinstance(exc, OverrideParseException):
        text = f"cannot parse the override {exc.override!r}: {text}"
    if isinstance(cause, OmegaConfBaseException):
        text += "; " + one_line(str(cause))
    hint = budget_hint(key)
    return f"{text}; {hint}" if hint else text


def _setup_error(exc: OSError) -> OutputError | None:
    """An output folder Hydra could not create or write before the app ran (no GRT code in the traceback)."""
    from hydra.errors import HydraException

    if isinstance(exc, HydraException) or not exc.filename:
        return None
    here, tb = Path(__file__).resolve(), exc.__traceback__
    package = here.parent
    while tb is not None:
        path = Path(tb.tb_frame.f_code.co_filename).resolve()
        if path != here and package in path.parents:
            return None  # raised by the app: its own error handling applies
        tb = tb.tb_next
    return OutputError(f"cannot write {exc.filename}: {exc.strerror}; give an output folder you can write "
                       "to: hydra.run.dir=PATH (hydra.sweep.dir=PATH with -m)")


def check_output_file(path: str | Path, suffixes: Iterable[str] | None = None, flag: str = "--out") -> Path:
    """Refuse an output file before any work: an unsupported extension, or a folder that does not exist.

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
    return path


def write_output(path: str | Path, data: bytes | str, flag: str = "--out PATH") -> None:
    """Write ``path`` whole or not at all (a temporary file renamed over it; Ctrl-C leaves no half file).

    Raises:
        OutputError: the folder is read-only or full (names the path and the fix).
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        tmp.write_bytes(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror}; choose a folder you can write to ({flag})") \
            from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
