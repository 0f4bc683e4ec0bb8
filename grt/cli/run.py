"""``grt-run`` (``python -m grt.run``): red-team a policy on a task and object; Hydra entry point.

Examples::

    python -m grt.run                                   # grasp task, default object, budget=quick
    python -m grt.run object=bottle selector=all optimizer=cma_es budget=paper
    python -m grt.run -m selector=heuristic,all optimizer=topdm,gaussian budget=smoke
    python -m grt.run -m hydra/launcher=slurm experiment=table1_insertion   # the jobs on SLURM (docs/cluster.md)
    python -m grt.run resume=outputs/grasp/mug/antipodal/heuristic-topdm/2026-11-23_01-00-00

``main`` resolves the config once and calls :func:`grt.runner.run`, a plain function tests import; it
returns the run's Final Drop so Hydra sweepers can optimize it.

A run writes its own config once, when it starts, to ``run_config.yaml`` (read-only), and ``resume=DIR``
alone is the whole command to continue it (:mod:`grt.runfolder`): :func:`cli` checks DIR and the command
before Hydra starts, so a refused resume writes nothing anywhere, and hands Hydra the run's own overrides;
``main`` then runs the saved config. A resume of a finished run with nothing left to do says so and
changes nothing (before Hydra writes a file); ``resume=`` with no folder (an unset shell variable) and a record
edited since the start are refused. Ctrl-C ends a run with one line naming the command that continues it
(exit code 130), and so does SIGTERM, how schedulers and ``timeout`` stop a job (exit code 143).

Every refusal is one ``error: ...`` line on stderr (exit code 2); a run refused before it saved anything
leaves no folder behind (:func:`grt.runfolder.lock.discard_new`). The folder is made and locked before Hydra
writes into it (:class:`grt.cli.callbacks.RunFolderCallback`): a second process in it is refused, naming the
first's PID, and a new run starts only in a new or empty folder (never over a run's record or the user's files). A full disk or a folder that cannot be written
mid-run is one line naming the disk and the command that continues the run (exit code 1). A sweep's job
that fails writes ``error.txt`` in its folder (with the command that continues it, if it had begun) and the
sweep goes on, and the sweep's command ends with one line on stderr naming the jobs that failed or never
finished, exit code 1 (:mod:`grt.cli.sweeps`; a sweep prints its folder when it starts and ends); under the
submitit launcher (``hydra/launcher=slurm``, :mod:`grt.cli.launchers`) a job that
died without a result (killed, out of time or memory) ends the sweep's command with one line naming it.
"""

from __future__ import annotations

import logging
import math
import sys
import traceback
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from grt.cli._common import (
    CONF_DIR,
    exit_on_user_error,
    find_user_error,
    launch,
    parse_command,
    recorded_config_dir,
    recorded_searchpath,
    run_cli,
)
from grt.cli.launchers import check_launcher, unfinished_job
from grt.cli.sweeps import STARTED, sweep_end
from grt.config import plain, saved_plan, validate
from grt.config.records import parse_overrides
from grt.errors import INTERRUPTED, TERMINATED, Terminated
from grt.plan import Budget
from grt.runfolder.lock import discard_new
from grt.runfolder.record import interrupted, is_run_folder, load_run_config, resume_command, storage_error
from grt.runfolder.resume import SHRINK_KEYS, own_config, resume_overrides
from grt.runner import AFTER_SEARCH, nothing_to_do, run

log = logging.getLogger("grt.run")


@hydra.main(config_path=CONF_DIR, config_name="run", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns Final Drop (NaN for a failed job of a sweep, which goes on)."""
    logging.raiseExceptions = False  # a full disk ends the run with one line, not a traceback per log record
    if cfg.resume:  # the run's own config, with what this command may change (grt.runfolder.resume)
        own = own_config(str(cfg.resume), plain(cfg))
        cfg = cfg if own is None else OmegaConf.create(own)
    run_dir = Path(cfg.resume or cfg.paths.output_dir)
    try:
        validate(cfg)  # budget ranges, +budget keys, optimizer settings: refused before any simulation
        summary = run(cfg)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (grt.errors.Terminated)
        stop, code = (("terminated (SIGTERM)", TERMINATED) if isinstance(exc, Terminated)
                      else ("interrupted (Ctrl-C)", INTERRUPTED))
        _say(interrupted(run_dir, stop), discard_new(run_dir))
        raise SystemExit(code) from None
    except Exception as exc:
        if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
            out = Path(cfg.paths.output_dir)  # the job's own folder (never a refused resume's)
            out.mkdir(parents=True, exist_ok=True)
            again = (f"; continue it with: {resume_command(out)}" if is_run_folder(out) else "")
            (out / "error.txt").write_text(traceback.format_exc() + again.lstrip("; ") + "\n" * bool(again))
            log.error("job failed (%s: %s); details in %s%s; the sweep goes on",
                      type(exc).__name__, exc, out / "error.txt", again)
            return math.nan
        found = find_user_error(exc)
        if found is not None:  # refused: one line on stderr, and a run that saved nothing leaves nothing
            _say(f"error: {found}", discard_new(run_dir))
            raise SystemExit(2) from None
        storage = storage_error(exc, run_dir)  # disk full, folder not writable: one line, how to go on
        if storage is not None:
            _say(f"error: {storage}", discard_new(run_dir))
            raise SystemExit(1) from None
        raise
    return float(summary["final_drop"])


def _say(line: str, also: str = "") -> None:
    """One line on stderr (the convention of every refusal and stop), ``also`` in brackets after it."""
    sys.stdout.flush()
    print(f"{line} ({also})" if also else line, file=sys.stderr, flush=True)


def _finished(overrides: list[str]) -> str | None:
    """:func:`grt.runner.nothing_to_do` for ``resume=DIR`` with ``overrides`` (checked by ``resume_overrides``),
    or ``None``: the run's own config with the ``budget.confirm_trials`` and shrink settings given; a setting made after the
    search (``report``, ``budget.videos``, ``logger``) given is work for the run itself to judge."""
    parsed = parse_overrides(overrides)
    run_dir = Path(next(o for o in reversed(parsed) if o.key == "resume").value)
    config = load_run_config(run_dir)
    budget = config["budget"]
    for key in SHRINK_KEYS:  # a run saved before the shrink existed: this command's defaults
        if budget.get(key.split(".")[1]) is None:
            budget[key.split(".")[1]] = getattr(Budget, key.split(".")[1])
    for o in parsed:
        if any(o.key == k or o.key.startswith((f"{k}.", f"{k}/")) for k in AFTER_SEARCH):
            return None
        if o.key in ("budget.confirm_trials", *SHRINK_KEYS):
            budget[o.key.split(".")[1]] = o.value
    return nothing_to_do(run_dir, saved_plan(config, run_dir))


def cli(argv: list[str] | None = None) -> None:
    """``grt-run``: a ``resume=`` is checked, and becomes the run's own command, before Hydra starts.

    The command line is read as ``@hydra.main`` reads it (:func:`grt.cli._common.parse_command`), and the
    command (with a resume's overrides) goes to :func:`main` through Hydra's public entry point
    (:func:`grt.cli._common.launch`); ``sys.argv`` is as it was when this returns.
    """
    args = parse_command(argv)
    with exit_on_user_error():
        launches = args.multirun and not (args.help or args.hydra_help)
        if launches:  # hydra/launcher=slurm where SLURM is missing: refused before anything is written
            check_launcher(args.overrides)
        if any("resume=" in arg for arg in args.overrides):
            given, args.overrides = args.overrides, resume_overrides(args.overrides)
            args.config_dir = args.config_dir or recorded_config_dir(args.overrides)  # the user's config folder
            args.overrides = [*recorded_searchpath(args.overrides), *args.overrides]  # ... or hydra.searchpath
            line = None if args.multirun or args.help or args.hydra_help else _finished(given)
            if line is not None:  # said before Hydra starts: not a file of the run is touched
                print(line, flush=True)
                return

    def run_app() -> None:
        started = len(STARTED)
        try:
            launch(main, args)
        except Exception as exc:
            line = unfinished_job(exc)  # a submitit job that died (killed, out of time or memory)
            if line is None:
                raise
            _say(f"error: {line}")
            raise SystemExit(1) from None
        if len(STARTED) > started:  # a sweep ran: its folder, its jobs, and exit code 1 when some failed
            code = sweep_end(STARTED[-1])
            if code:
                raise SystemExit(code)

    run_cli(run_app)
