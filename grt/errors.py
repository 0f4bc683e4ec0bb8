"""One error path for GRT's command-line tools: a user's mistake is one line and exit code 2.

Errors in what the user gave (object, mesh, journal, checkpoint, plug, VLM or score settings) carry a message
that names the problem and the fix; :func:`exit_on_user_error` prints it without a traceback.
"""

from __future__ import annotations

import contextlib
import logging
import sys

log = logging.getLogger("grt")


def user_errors() -> tuple[type[BaseException], ...]:
    """The exception types that mean "the input is wrong" (imported lazily: no simulator import)."""
    from grt.blueteam.core import BlueTeamError
    from grt.evaluators.collision import CollisionError
    from grt.geometry.mesh import MeshError
    from grt.journal import JournalError
    from grt.objects import UnknownObjectError
    from grt.policies.rsl_rl import CheckpointError
    from grt.scores import ScoreConfigError
    from grt.selectors.client import VLMError
    from grt.tasks.base import TaskInputError

    return (MeshError, UnknownObjectError, JournalError, VLMError, CollisionError, CheckpointError, TaskInputError,
            BlueTeamError, ScoreConfigError)


def find_user_error(exc: BaseException) -> BaseException | None:
    """The user error behind ``exc`` (Hydra wraps errors raised while instantiating), or ``None``."""
    kinds = user_errors()
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, kinds):
            return exc
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


@contextlib.contextmanager
def exit_on_user_error():
    """Turn a user error into ``error: <message>`` on stderr and exit code 2."""
    try:
        yield
    except Exception as exc:
        found = find_user_error(exc)
        if found is None:
            raise
        print(f"error: {found}", file=sys.stderr)
        raise SystemExit(2) from None
