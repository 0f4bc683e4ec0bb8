"""The Python a simulator worker runs: folders a policy puts first on its workers' import path.

Some policies need libraries that cannot live in GRT's own environment. ManiSkill's motion planners need
mplib, and every mplib wheel (0.1.0, 0.1.1, 0.2.1) crashes in ``Planner()`` under numpy 2: their workers
must import numpy 1.26 instead. Such a policy's config names the folders in ``worker_path`` (a path or a
list)::

    # conf/policy/motion_planner.yaml
    _target_: grt.policies.motion_planner.MotionPlannerPolicy
    worker_path: ${paths.motionplanning}     # numpy 1.26.4, made by `make motionplanning`

and every worker process that runs the policy starts with them first on ``sys.path``; the main process
never imports from them. A process pool's workers (``spawn``) take their ``sys.path`` from the parent when
they start, so :func:`spawn_path` puts the folders first on the parent's path for the moment of the start
(nothing is imported meanwhile: the parent's numpy is loaded long before); Ray actors get them first in
``PYTHONPATH`` (:mod:`grt.evaluators.ray_pool`).

Parent and workers then run different numpys and exchange pickles (jobs with vertex arrays, trial outcomes):
numpy 1.26 reads numpy 2's pickles of protocol 4 (``multiprocessing`` on Python < 3.14), but not those of
protocol 5 (Ray, and ``multiprocessing`` from Python 3.14 on), which name ``numpy._core.numeric``:
:func:`accept_numpy2_pickles` maps that name in a worker on numpy 1.x. numpy 2 reads numpy 1.26's
pickles as they are (its ``numpy.core`` aliases).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
from pathlib import Path

from grt.errors import UserError

#: the policy config key naming the folders its workers import from first
KEY = "worker_path"


class WorkerPathError(UserError):
    """A policy's ``worker_path`` that cannot be used (a folder that does not exist, a start method that
    cannot apply it)."""


def worker_path(policy: dict | None) -> list[str]:
    """The folders ``policy["worker_path"]`` names (one path or a list), absolute, in order; ``[]`` for none.

    Raises:
        WorkerPathError: a folder that does not exist (the policy's own set-up makes it).
    """
    value = (policy or {}).get(KEY)
    if not value:
        return []
    folders = [value] if isinstance(value, str | os.PathLike) else list(value)
    found = []
    for folder in folders:
        path = Path(folder).expanduser().resolve()
        if not path.is_dir():
            target = (policy or {}).get("_target_", "the policy")
            raise WorkerPathError(f"policy.{KEY}: {path} does not exist; {target} runs its workers with it first "
                                  "on their path: run the set-up its config names (e.g. `python -m grt.setup motionplanning`)")
        found.append(str(path))
    return found


@contextlib.contextmanager
def spawn_path(folders: list[str]):
    """While a worker process is started with ``spawn``: ``folders`` first on this process's ``sys.path``
    (what the child sets as its own before it imports anything of the parent's) and in ``PYTHONPATH``."""
    if not folders:
        yield
        return
    saved_path, saved_env = list(sys.path), os.environ.get("PYTHONPATH")
    sys.path[:0] = folders
    os.environ["PYTHONPATH"] = os.pathsep.join([*folders, *([saved_env] if saved_env else [])])
    try:
        yield
    finally:
        sys.path[:] = saved_path
        if saved_env is None:
            os.environ.pop("PYTHONPATH", None)
        else:
            os.environ["PYTHONPATH"] = saved_env


def python_path(folders: list[str], rest: str | None) -> str:
    """A ``PYTHONPATH`` value with ``folders`` first, then ``rest`` (``None``: nothing more)."""
    return os.pathsep.join([*folders, *([rest] if rest else [])])


def accept_numpy2_pickles() -> None:
    """Let this process, when it runs numpy 1.x, read numpy 2's protocol-5 array pickles (idempotent).

    numpy 2 pickles an array at protocol 5 as ``numpy._core.numeric._frombuffer``; numpy 1.26 ships a
    ``numpy._core`` stub with ``multiarray`` and ``umath`` only. Nothing to do under numpy 2.
    """
    import numpy

    if int(numpy.__version__.split(".")[0]) >= 2 or "numpy._core.numeric" in sys.modules:
        return
    with contextlib.suppress(ImportError):  # numpy < 1.26 has no numpy._core at all: nothing to map onto
        importlib.import_module("numpy._core")
        sys.modules["numpy._core.numeric"] = importlib.import_module("numpy.core.numeric")


def run_in_worker(folders: list[str], function, *args):
    """``function(*args)`` in a spawned process whose import path starts with ``folders`` (a command that runs a
    policy in its own process, e.g. ``grt.calibrate``, runs it there instead when the policy has a
    ``worker_path``); returns its result. ``function`` must be importable by name (a module-level function).

    Raises:
        the function's own :class:`grt.errors.UserError` (re-raised with its message), or RuntimeError when
        it failed otherwise or the process died.
    """
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_call, args=(child, function, args), daemon=True)
    with spawn_path(folders):
        proc.start()
    child.close()
    try:
        kind, value = parent.recv()
    except EOFError:
        proc.join()
        raise RuntimeError(f"the process running {function.__name__} died (exit code {proc.exitcode})") from None
    finally:
        proc.join(timeout=30)
        parent.close()
    if kind == "user":
        raise UserError(value)
    if kind == "error":
        raise RuntimeError(value)
    return value


def _call(conn, function, args) -> None:
    """The child of :func:`run_in_worker`."""
    import traceback

    accept_numpy2_pickles()
    try:
        conn.send(("ok", function(*args)))
    except UserError as exc:
        conn.send(("user", str(exc)))
    except Exception:  # noqa: BLE001 - the parent says it, with the traceback
        conn.send(("error", traceback.format_exc()))
    finally:
        conn.close()
