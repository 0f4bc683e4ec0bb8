"""A ``grt.run`` sweep (``-m``) says where it writes and how its jobs ended.

:class:`SweepFolder` (a Hydra callback of ``conf/hydra/default.yaml``) prints the sweep's folder when the sweep
starts; :func:`sweep_end` (called by :func:`grt.cli.run.cli` once Hydra's launcher returns) prints it again
with the count of its jobs, and when some failed (a job's ``main`` wrote ``error.txt`` and the sweep went on)
or never finished (no ``summary.json``), one line on stderr naming them and their logs, and the sweep's command
exits with code 1: a sweep whose jobs failed is not a success. A sweep run again in the folder of an earlier one
(``hydra.sweep.dir``, to go on from its journals) is judged by its own jobs: a failed or unfinished job folder
none of whose files this sweep touched (an earlier sweep's, e.g. under a job name GRT no longer makes) is named
on stdout, not counted as this sweep's failure.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from grt.report.tables import ReportError, collect, unfinished

#: the folders of the sweeps this process started (the last one is the running sweep's)
STARTED: list[Path] = []
#: each started sweep folder's files when the sweep started (path -> (mtime_ns, size))
BEFORE: dict[Path, dict[str, tuple[int, int]]] = {}


def _files(folder: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``folder`` with its modification time and size (what a job that ran changed)."""
    out = {}
    for path in folder.rglob("*"):
        try:
            if path.is_file():
                st = path.stat()
                out[str(path)] = (st.st_mtime_ns, st.st_size)
        except OSError:  # removed while we looked
            continue
    return out


class SweepFolder(Callback):
    """Prints ``sweep folder: DIR`` when a sweep starts, and keeps DIR for :func:`sweep_end`."""

    def on_multirun_start(self, config: DictConfig, **kwargs) -> None:
        try:
            folder = Path(str(config.hydra.sweep.dir))
        except Exception:  # noqa: BLE001 - a folder name Hydra cannot resolve: Hydra reports it
            return
        STARTED.append(folder)
        BEFORE[folder] = _files(folder) if folder.is_dir() else {}
        print(f"sweep folder: {folder}", flush=True)


def sweep_end(folder: Path) -> int:
    """Say how the sweep in ``folder`` ended: its folder and job count on stdout, its failed and unfinished
    jobs on stderr (one line: each job, where its log is). Returns the exit code: 0, or 1 when any job failed
    or did not finish."""
    try:
        rows, failed = collect(folder) if folder.is_dir() else ([], [])
    except ReportError:
        rows, failed = [], []
    waiting = unfinished(folder) if folder.is_dir() else []
    total = len(rows) + len(failed) + len(waiting)
    report = f"python -m grt.report {shlex.quote(str(folder))}"
    print(f"sweep folder: {folder} ({total} job{'s' * (total != 1)}; the table: {report})", flush=True)
    before = BEFORE.get(folder)
    if before is not None:  # a job folder this sweep never touched is an earlier sweep's: named, not counted
        older = [p for p in [*failed, *waiting] if not _ran(p, before)]
        failed, waiting = [p for p in failed if p not in older], [p for p in waiting if p not in older]
        if older:
            print(f"{len(older)} job folder{'s' * (len(older) != 1)} of an earlier sweep here, not run by this one, "
                  f"did not finish: {', '.join(p.name for p in older)} (left as they were; go on with one by "
                  f"python -m grt.run resume=DIR)", flush=True)
    bad = [f"{p.name} (error: {p / 'error.txt'})" for p in failed]
    bad += [f"{p.name} (no summary.json; its log: {p / 'run.log'})" for p in waiting]
    if not bad:
        return 0
    sys.stdout.flush()
    print(f"error: {len(bad)} of {total} jobs of the sweep failed: {', '.join(bad)}; {report} lists them",
          file=sys.stderr, flush=True)
    return 1


def _ran(job: Path, before: dict[str, tuple[int, int]]) -> bool:
    """Whether a job of this sweep ran in ``job``: a file there is new or changed since the sweep started."""
    now = _files(job)
    return not now or any(before.get(path) != stat for path, stat in now.items())
