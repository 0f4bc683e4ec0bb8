"""One process per run folder: the folder's lock, and a new run only in a new or empty folder.

A GRT app that writes a run folder (``grt.run``, ``grt.train``, ``grt.blueteam``, ``grt.evaluate``,
``grt.select``) :func:`claim` s it before Hydra writes there (the app layer's Hydra callback,
:class:`grt.cli.callbacks.RunFolderCallback`): the folder is made and locked (an ``flock`` on ``.grt.lock``,
holding the PID), a new run in a red-team run's folder or in any other folder that is not empty is refused,
and a run refused before it saved anything leaves nothing behind (:func:`discard_new`).
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from grt.errors import OutputError, UserError
from grt.runfolder.record import (
    RUN_CONFIG,
    ResumeError,
    is_run_folder,
    is_study_folder,
    is_training_folder,
    resume_command,
)

LOCK = ".grt.lock"  # in the run folder while a process runs there: its PID, under an exclusive flock


class FolderBusyError(UserError):
    """Another process holds the run folder's lock."""


class FolderNotEmptyError(UserError):
    """A new run (of any GRT app) given a folder that already holds files: the user's, or another command's."""


# What Hydra writes when an app starts (besides ``<app>.log``): a folder holding only these and the log is a
# start that was killed before it saved anything, which a new start may take over.
HYDRA_RECORD = {"config.yaml", "hydra.yaml", "overrides.yaml"}
# Apps whose folder may be inside a red-team run's: a profile of the run (RUN/profile/<time>, no summary.json).
INSIDE_RUN_APPS = ("profile",)


_held: dict[Path, int] = {}  # run folder (resolved) -> this process's locked file descriptor of its LOCK
_claimed: dict[Path, tuple[Path | None, set[str], set[str]]] = {}  # run folder -> (first folder made for it,
# what the folder held before this command, the names of Hydra's files)


def acquire(run_dir: str | Path) -> bool:
    """Take ``run_dir``'s exclusive lock (an ``flock`` on ``run_dir/.grt.lock``, holding this PID) for this
    process's run; ``False`` if this process holds it already. The folder must exist. The kernel releases
    the lock when the process ends, however it ends (a SIGKILL leaves the file, never a stale lock).

    Raises:
        FolderBusyError: another process holds it (names the folder and that process's PID).
        OSError: the lock file cannot be written.
    """
    key = Path(run_dir).resolve()
    if key in _held:
        return False
    path = key / LOCK
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise FolderBusyError(
                f"{run_dir} is in use by another GRT process (PID {holder}, which holds {path}): two processes in "
                "one folder would mix their files (a run's journal, a fine-tune's checkpoints). Wait for it to end "
                "(or stop it), or give this command another folder (hydra.run.dir=PATH)") from None
        try:  # the previous holder removes the file as it lets go: locked, it must still be the file
            current = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            current = False
        if current:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
    except OSError:
        os.close(fd)
        raise
    _held[key] = fd
    return True


def release(run_dir: str | Path) -> None:
    """Let go of ``run_dir``'s lock if this process holds it (the lock file is removed)."""
    key = Path(run_dir).resolve()
    fd = _held.pop(key, None)
    if fd is None:
        return
    with contextlib.suppress(OSError):
        os.unlink(key / LOCK)  # before closing: a process waiting on it sees another file and retries
    os.close(fd)


@contextlib.contextmanager
def locked(run_dir: str | Path) -> Iterator[None]:
    """Hold ``run_dir``'s lock for the block (nothing to do if this process holds it already)."""
    took = acquire(run_dir)
    try:
        yield
    finally:
        if took:
            release(run_dir)


@atexit.register
def _release_all() -> None:
    for key in list(_held):
        release(key)


def claim(run_dir: Path, resume: str | None, log_file: str = "run.log", app: str = "run") -> None:
    """Make and lock the folder of a GRT app's run (``python -m grt.<app>``) before Hydra writes anything
    into it.

    Refuses a new run in a folder that holds a red-team run (its record would be rewritten and two runs'
    journals mixed; or, for another app, the run's files overwritten by its own), a new run in any other
    folder that is not empty (:func:`check_new_folder`: the user's own files, or another command's), and a
    folder another process runs in; notes what this command makes, so that a run refused before it saved
    anything leaves nothing behind (:func:`discard_new`). ``log_file``: the name of Hydra's log file
    (``<app>.log``).

    Raises:
        ResumeError: a new run (no ``resume=``) in a red-team run's folder, or another app's command (resumed
            or not) there: only ``grt.run`` continues a red-team run.
        FolderNotEmptyError: a new run in a folder that holds other files.
        FolderBusyError: another process holds the folder's lock.
        OutputError: the folder cannot be made or written.
    """
    # absolute: discard_new gets Hydra's absolute output_dir, the callback may get a relative run.dir
    first_new = next((p for p in reversed([run_dir.resolve(), *run_dir.resolve().parents]) if not p.exists()), None)
    hydra_files = {".hydra", log_file}
    before = set(os.listdir(run_dir)) if run_dir.is_dir() else set()
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
        acquire(run_dir)  # first: a folder a run is running in is "in use", whatever this command is
    except OSError as exc:
        _remove_new(run_dir, first_new)
        raise OutputError(f"cannot write the run folder {run_dir}: {exc.strerror}; give a folder you can write to "
                          "(hydra.run.dir=PATH)") from None
    if is_run_folder(run_dir) and (app != "run" or not resume):
        release(run_dir)
        if app != "run":  # only grt.run continues a red-team run; any other app would write over its files
            given = f"resume={resume}: {run_dir}" if resume else f"hydra.run.dir={run_dir}"
            raise ResumeError(f"{given} already holds a red-team run ({RUN_CONFIG} there), whose "
                              f"files python -m grt.{app} would overwrite or mix with its own: give it a folder of "
                              "its own (hydra.run.dir=PATH, or leave it out for a new one)")
        raise ResumeError(f"hydra.run.dir={run_dir} already holds a run ({RUN_CONFIG} there), which this command "
                          f"would overwrite: continue it with {resume_command(run_dir)}, or give a new folder")
    if not resume or Path(resume).resolve() != run_dir.resolve():
        try:
            check_new_folder(run_dir, before, app, log_file)
        except FolderNotEmptyError:
            release(run_dir)
            _remove_new(run_dir, first_new)  # a folder made inside a run's: not left there
            raise
    _claimed[run_dir.resolve()] = (first_new, before, hydra_files)


def check_new_folder(run_dir: Path, before: set[str], app: str, log_file: str) -> None:
    """Refuse a new run of ``python -m grt.<app>`` in ``run_dir`` unless the folder is new or empty (``before``:
    the names it held), or holds only a start of the same app killed before it saved anything (Hydra's
    record and ``log_file``), or is a folder the app continues in place (a ``grt.blueteam`` study, a
    ``grt.train`` training).

    A folder inside a red-team run's folder is refused too, whatever it holds, but a robustness profile's
    (:data:`INSIDE_RUN_APPS`): ``python -m grt.profile run=RUN`` writes ``RUN/profile/<time>`` (no summary, so
    ``grt.report RUN`` reads it as the run's profile, never as another run).

    Raises:
        FolderNotEmptyError: names the folder, what it holds (or the run it is inside) and what to do.
    """
    outer = next((p for p in Path(run_dir).resolve().parents if is_run_folder(p)), None)
    if outer is not None and app not in INSIDE_RUN_APPS:  # its files would join the run's (grt.report would average)
        raise FolderNotEmptyError(f"{run_dir} is inside the red-team run {outer}: a new python -m grt.{app} there "
                                  "would mix its files with that run's (python -m grt.report would read both as one "
                                  "folder's); give a folder outside it (hydra.run.dir=PATH)")
    held = sorted(before - {LOCK})
    hydra = run_dir / ".hydra"
    killed_start = set(held) <= {".hydra", log_file} and (
        not hydra.is_dir() or {p.name for p in hydra.iterdir()} <= HYDRA_RECORD)
    in_place = (app == "blueteam" and is_study_folder(run_dir)) or (app == "train" and is_training_folder(run_dir))
    if not held or killed_start or in_place:
        return
    shown = ", ".join(held[:4]) + (f" and {len(held) - 4} more" if len(held) > 4 else "")
    flag = "hydra.run.dir=PATH" + (" or out_dir=PATH" if app == "select" else "")
    raise FolderNotEmptyError(f"{run_dir} is not empty (it holds {shown}): a new python -m grt.{app} starts only in a "
                              f"new or empty folder, so that nothing there is overwritten or mixed with its files; "
                              f"give another folder ({flag}), or leave it out for a new one")


def discard_new(run_dir: Path) -> str:
    """Remove what this command made for a run that saved nothing (the folder holds only Hydra's files):
    the folder it created, or its Hydra files in a folder that was there. Returns the words saying so
    ("" if nothing was removed)."""
    key = Path(run_dir).resolve()
    if key not in _claimed or is_run_folder(run_dir):
        return ""
    first_new, before, hydra_files = _claimed[key]
    made = {p.name for p in run_dir.iterdir()} - before - {LOCK} if run_dir.is_dir() else set()
    if not made <= hydra_files:  # the command saved something of its own: keep it all
        return ""
    del _claimed[key]
    release(run_dir)
    if first_new is not None:
        _remove_new(run_dir, first_new)
        return f"nothing was saved and the new folder {run_dir} was removed"
    for name in made:
        path = run_dir / name
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
    return f"nothing was saved in {run_dir}"


def _remove_new(run_dir: Path, first_new: Path | None) -> None:
    """Remove ``run_dir`` and the empty folders above it up to ``first_new`` (those this command made)."""
    if first_new is None:
        return
    run_dir, first_new = Path(run_dir).resolve(), Path(first_new).resolve()
    made = [run_dir, *run_dir.parents]
    if first_new not in made:  # not a folder this command made above the run's: remove nothing
        return
    shutil.rmtree(run_dir, ignore_errors=True)
    for folder in made[1:made.index(first_new) + 1]:
        with contextlib.suppress(OSError):
            folder.rmdir()  # only an empty one: a folder another run made meanwhile stays


