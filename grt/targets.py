"""The classes a config names with ``_target_`` (policy, task session, selector, optimizer, evaluator, logger,
a user's own among them): checked before anything is written, and built with one-line errors.

:func:`check_target` runs in :func:`grt.config.validate`, each app's first step: every ``_target_`` of the
composed config must import, and every key of its node must be an argument its class takes, so a class
Python cannot find, or a misspelled argument, is refused in one line before a folder is saved or a worker
started. :func:`build` instantiates a node as Hydra does; a constructor that raises is one line naming the
class and the error's first line, with the whole traceback in a file (:func:`save_traceback`), because the
refused command leaves no folder to keep it in. A task session is built in the evaluator's workers:
:func:`worker_error` words what a worker sent back the same way.
"""

from __future__ import annotations

import contextlib
import difflib
import importlib
import inspect
import os
import tempfile
import time
import traceback
from pathlib import Path

from grt.errors import UserError

HYDRA_KEYS = ("_target_", "_partial_", "_args_", "_recursive_", "_convert_")
HOW_TO_IMPORT = ("make it importable: install your package (pip install -e YOUR_PROJECT) or add the folder "
                 "that holds it to PYTHONPATH")


class ClassError(UserError):
    """A class named by ``_target_`` that cannot be imported, is given an argument it does not take, or
    whose constructor raised; the message names the config key, the class and the fix."""


def check_target(key: str, node, arguments: bool = True) -> None:
    """Import ``node._target_`` and check that it takes every key of ``node`` as an argument (``arguments``).

    Raises:
        ClassError: a module or class that does not import (naming both, and how to make it importable),
            or an argument the class does not take (listing those it takes).
    """
    target = str(node["_target_"])
    given = [str(k) for k in node if k not in HYDRA_KEYS]
    params = _source_parameters(target)  # GRT's own simulator classes: read, not imported (seconds a command)
    if params is _UNREAD:
        obj = locate(target, key)
        params = _parameters(obj) if arguments else None
    elif not arguments:
        params = None
    if params is not None:
        for name in given:
            if name not in params:
                close = difflib.get_close_matches(name, params, n=1)
                hint = f"; did you mean {key}.{close[0]}?" if close else ""
                takes = ", ".join(params) if params else "no arguments"
                raise ClassError(f"{describe(key, target)} takes no argument {name!r} (it takes: {takes}){hint}")


def takes(target: str, name: str) -> bool:
    """Whether the class (or function) ``target`` takes a keyword argument ``name`` (``False`` when it cannot be
    imported or its signature read)."""
    params = _source_parameters(target)
    if params is _UNREAD:
        try:
            params = _parameters(locate(target))
        except ClassError:
            return False
    return params is not None and name in params


def locate(target: str, key: str = "_target_") -> object:
    """The object a dotted path names (``mypkg.policies.MyPolicy``), imported.

    Raises:
        ClassError: no module of the path imports (the one Python cannot find is named), importing the
            module raised (its error, the traceback in a file), or the module lacks the name.
    """
    parts = target.split(".")
    if not target or not all(p.isidentifier() for p in parts):
        raise ClassError(f"{key}._target_={target!r} is not a dotted path to a class (e.g. mypkg.policies.MyPolicy)")
    missing = parts[0]
    for i in range(len(parts), 0, -1):
        module_name = ".".join(parts[:i])
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name and (module_name == exc.name or module_name.startswith(f"{exc.name}.")):
                missing = exc.name
                continue  # no such module: the name is an attribute of a shorter one
            raise build_error(key, target, f"importing {module_name}", exc) from None
        except Exception as exc:  # noqa: BLE001 - the user's module raised while Python imported it
            raise build_error(key, target, f"importing {module_name}", exc) from None
        obj = module
        for depth, name in enumerate(parts[i:], start=i):
            if not hasattr(obj, name):
                where = f" ({module.__file__})" if getattr(module, "__file__", None) else ""
                owner = ".".join(parts[:depth])
                if missing == f"{owner}.{name}" and depth < len(parts) - 1:  # a module of the path is not there
                    raise ClassError(f"{key}._target_={target}: Python cannot import the module {missing!r} "
                                     f"({owner}{where} has no {name}); {HOW_TO_IMPORT}")
                names = [n for n in dir(obj) if not n.startswith("_")]
                close = difflib.get_close_matches(name, names, n=1)
                hint = f"; did you mean {owner}.{close[0]}?" if close else ""
                raise ClassError(f"{key}._target_={target}: {owner}{where if depth == i else ''} has no "
                                 f"{name!r}{hint}")
            obj = getattr(obj, name)
        return obj
    raise ClassError(f"{key}._target_={target}: Python cannot import the module {missing!r}; {HOW_TO_IMPORT}")


#: :func:`_source_parameters` could not read the class from its source: import it.
_UNREAD = object()


def _source_parameters(target: str):
    """The keyword arguments of one of GRT's own classes (``grt.tasks.grasp.GraspSession``), read from its
    module's source without importing it, or :data:`_UNREAD`.

    Importing a task session imports the simulator (2-3 s), which a command that refuses its input in its
    first second should not wait for; GRT's own modules import by construction, so what is left to check is
    the keys. Read only where the class is defined in that module with an ``__init__`` of its own (``None``:
    it takes ``**kwargs``); anything else, or a module already imported, is left to :func:`locate`.
    """
    import ast
    import importlib.util
    import sys

    module, _, name = target.rpartition(".")
    if not module.startswith("grt.") or module in sys.modules:
        return _UNREAD
    try:
        spec = importlib.util.find_spec(module)
        source = spec.loader.get_source(module) if spec is not None and spec.loader is not None else None
        tree = ast.parse(source) if source else None
    except (ImportError, ValueError, SyntaxError, AttributeError):
        return _UNREAD
    cls = next((n for n in (tree.body if tree else []) if isinstance(n, ast.ClassDef) and n.name == name), None)
    init = next((n for n in (cls.body if cls else []) if isinstance(n, ast.FunctionDef) and n.name == "__init__"),
                None)
    if init is None:
        return _UNREAD
    if init.args.kwarg is not None:
        return None
    return [a.arg for a in [*init.args.posonlyargs, *init.args.args][1:] + init.args.kwonlyargs]

def instantiate(node, **kwargs):
    """``node`` (a mapping with ``_target_``) instantiated as Hydra does, with no error handling of GRT's (a
    worker reports its own failures, :func:`worker_error`): with :func:`build`, the library's only way to
    make an object of a config node."""
    from hydra.utils import instantiate as hydra_instantiate

    return hydra_instantiate(node, **kwargs)


def build(node, key: str, **kwargs):
    """Instantiate ``node`` as Hydra does; a ``_partial_`` node is then called with ``kwargs`` (the arguments
    known only at run time), any other gets them as extra arguments.

    Raises:
        UserError: the constructor's own user error, as it is (its message names its fix).
        ClassError: any other error of the constructor: the class, the error's first line and the file
            that holds the whole traceback.
    """
    target = str(node["_target_"])
    locate(target, key)
    try:
        if node.get("_partial_", False):
            return instantiate(node)(**kwargs)
        return instantiate(node, **kwargs)
    except Exception as exc:  # noqa: BLE001 - one line for whatever the user's constructor raised
        found = _user_error(exc)
        if found is not None:
            raise found from exc
        raise build_error(key, target, "building it", exc) from None


def worker_error(key: str, target: str, trace: str, where: str = "an evaluator worker") -> ClassError:
    """One line for a class a worker process could not build (``trace``: the worker's formatted traceback):
    the error it names is the first of a chain (the constructor's own, before Hydra's wrapper); the whole
    traceback goes to a file (:func:`save_traceback`)."""
    first = trace.split("The above exception was the direct cause of the following exception:")[0]
    last = next((line for line in reversed(first.strip().splitlines()) if line.strip()), "an error")
    path = save_traceback(trace, target.rsplit(".", 1)[-1])
    return ClassError(f"{describe(key, target)} could not be built in {where}: {_first_line(last)} (the whole "
                      f"traceback: {path})")


def describe(key: str, target: str) -> str:
    """``policy=mine (mypkg.MyPolicy)``: the config key with the option the running app chose, and the class."""
    choice = _choice(key)
    return f"{key}={choice} ({target})" if choice else f"{key} ({target})"


def save_traceback(text: str, name: str = "error") -> Path:
    """Write a traceback to ``$TMPDIR/grt-errors/<time>-<pid>-<name>.txt`` and return the path (a refused
    command leaves no folder of its own to keep it in)."""
    folder = Path(tempfile.gettempdir()) / "grt-errors"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}-{name}.txt"
    path.write_text(text)
    return path


def _parameters(obj) -> list[str] | None:
    """The names ``obj`` takes as keyword arguments, or ``None`` when it takes any (``**kwargs``) or its
    signature cannot be read."""
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):
        return None
    kinds = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    if any(p.kind == inspect.Parameter.VAR_KEYWORD for p in signature.parameters.values()):
        return None
    return [name for name, p in signature.parameters.items() if p.kind in kinds]


def build_error(key: str, target: str, doing: str, exc: BaseException) -> ClassError:
    """One line for ``exc``, raised while ``doing`` something with the class of ``key``; the traceback goes to
    a file (:func:`save_traceback`). Hydra's ``InstantiationException`` is looked through: the line names the
    constructor's own error."""
    text = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    path = save_traceback(text, target.rsplit(".", 1)[-1])
    root = _root(exc)
    return ClassError(f"{describe(key, target)}: {doing} raised {type(root).__name__}: {_first_line(str(root))} "
                      f"(the whole traceback: {path})")


def _root(exc: BaseException) -> BaseException:
    """The error behind Hydra's ``InstantiationException`` (the constructor's own)."""
    seen = 0
    while type(exc).__name__ == "InstantiationException" and exc.__cause__ is not None and seen < 10:
        exc, seen = exc.__cause__, seen + 1
    return exc


def _user_error(exc: BaseException) -> UserError | None:
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, UserError):
            return exc
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


def _first_line(text: str) -> str:
    lines = [line.strip() for line in str(text).strip().splitlines() if line.strip()]
    return lines[0] if lines else "(no message)"


def _choice(key: str) -> str | None:
    """The option of group ``key`` the running Hydra app chose (``policy`` -> ``mine``), or ``None``."""
    with contextlib.suppress(Exception):
        from hydra.core.hydra_config import HydraConfig

        if HydraConfig.initialized():
            found = HydraConfig.get().runtime.choices.get(key)
            return str(found) if found is not None else None
    return None
