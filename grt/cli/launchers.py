"""Sweeps on a SLURM cluster: ``python -m grt.run -m hydra/launcher=slurm ...`` (``conf/hydra/launcher/slurm.yaml``).

Each job of the sweep is a SLURM job (one array), submitted by Hydra's submitit launcher
(hydra-submitit-launcher, whose ``submitit_slurm`` config ``slurm.yaml`` extends): the job unpickles the
app's function and runs it as a job of a local sweep does, in its own folder under ``hydra.sweep.dir``, with
submitit's logs under ``hydra.sweep.dir/.submitit``. On a machine without SLURM the command is refused in one
line (:func:`check_launcher`, before Hydra starts; :func:`no_slurm`). The resolvers here fill
``slurm.yaml``'s defaults from the run's config (its memory from ``budget.workers``, the Python environment
that submitted). docs/cluster.md has the whole story.
"""

from __future__ import annotations

import math
import re
import shutil
import sys
from pathlib import Path

from grt.config import add_resolver
from grt.errors import UserError

#: a job's memory: the run's own process, and one simulator worker each (grt.evaluators.pool.WORKER_MB,
#: the largest worker RSS measured, rounded up: docs/benchmarks.md, "Worker memory")
DRIVER_GB = 2.0
WORKER_GB = 1.0
NO_SLURM = 'Could not detect "srun"'  # submitit's words on a machine without SLURM
#: the launchers (``hydra/launcher=...``) that submit to SLURM: GRT's and the plugin's own
SLURM_LAUNCHERS = ("slurm", "submitit_slurm")


class SlurmUnavailable(UserError):
    """``hydra/launcher=slurm`` (or ``submitit_slurm``) on a machine where SLURM's commands are missing."""


def no_slurm(launcher: str = "slurm") -> SlurmUnavailable:
    """The refusal of ``hydra/launcher=<launcher>`` on this machine (names the fix)."""
    return SlurmUnavailable(
        f"hydra/launcher={launcher} submits the sweep's jobs to SLURM, but this machine has no SLURM (no srun or "
        "sbatch on PATH): run the command on the cluster's login node, or try the sweep here with "
        "hydra/launcher=submitit_local (or leave hydra/launcher out)")


def check_launcher(overrides: list[str]) -> None:
    """Refuse a SLURM launcher chosen on the command line where SLURM is missing, before Hydra writes the
    sweep's folder (submitit itself refuses only when it submits; :mod:`grt.cli._common` turns that into the
    same line).

    Raises:
        SlurmUnavailable: names the launcher and what to do instead.
    """
    for override in overrides:
        key, _, value = override.partition("=")
        if key.lstrip("+~") == "hydra/launcher" and value in SLURM_LAUNCHERS and not slurm_here():
            raise no_slurm(value)


def slurm_here() -> bool:
    """Whether SLURM's ``srun`` and ``sbatch`` are on this machine's PATH."""
    return shutil.which("srun") is not None and shutil.which("sbatch") is not None


def unfinished_job(exc: BaseException) -> str | None:
    """One line for a submitit job of the sweep that ended without a result (killed, out of memory or time,
    stopped), from submitit's ``UncompletedJobError``: the job, the last line of its log (GRT's own last
    words, e.g. how to continue the run), where its log is and how to go on; ``None`` for other errors."""
    for _ in range(10):
        if exc is None:
            return None
        if type(exc).__name__ == "UncompletedJobError" and type(exc).__module__.startswith("submitit"):
            break
        exc = exc.__cause__ or exc.__context__
    else:
        return None
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    head = " ".join(lines[:2]) if lines else type(exc).__name__
    match = re.search(r"with path (\S+)_result\.pkl", head)
    words = re.sub(r" with path \S+", "", head).rstrip(".")
    last = next((line for line in reversed(lines[2:]) if not set(line) <= {"-"} and "stream produced" not in line),
                None)
    text = f"a job of the sweep did not finish: {words}"
    if last:
        text += f"; its log ends: {last!r}"
    if match:
        stem = Path(match[1])
        text += (f" (all of it: {stem}_log.err); the jobs that finished keep their run folders in "
                 f"{stem.parents[2]} (python -m grt.report {stem.parents[2]}), a run cut short continues with "
                 "python -m grt.run resume=<its folder>")
    return text


def job_mem_gb(workers) -> int:
    """A sweep job's memory in GB (``hydra.launcher.mem_gb``): ``DRIVER_GB + WORKER_GB`` per worker."""
    return int(math.ceil(DRIVER_GB + WORKER_GB * max(int(workers), 1)))


def register() -> None:
    """Register ``grt_job_mem_gb`` and ``grt_python_prefix`` (idempotent)."""
    add_resolver("grt_job_mem_gb", job_mem_gb)
    # the environment (venv) of the Python running this command: what the jobs activate
    add_resolver("grt_python_prefix", lambda: sys.prefix)


register()
