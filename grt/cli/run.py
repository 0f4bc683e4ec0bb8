"""``grt-run`` (``python -m grt.run``): red-team a policy on a task and object; Hydra entry point.

Examples::

    python -m grt.run                                   # grasp task, default object, budget=quick
    python -m grt.run object=bottle selector=all optimizer=cma_es budget=paper
    python -m grt.run -m selector=heuristic,all optimizer=topdm,gaussian budget=smoke
    python -m grt.run resume=outputs/grasp/mug/heuristic-topdm/2026-11-23_01-00-00

``main`` resolves the config once and calls :func:`grt.runner.run`, a plain function tests import; it
returns the run's Final Drop so Hydra sweepers can optimize it.

A run writes its own config once, when it starts, to ``run_config.yaml`` (read-only), and ``resume=DIR``
alone is the whole command to continue it (:mod:`grt.runfolder`): :func:`cli` checks DIR and the command
before Hydra starts, so a refused resume writes nothing anywhere, and hands Hydra the run's own overrides;
``main`` then runs the saved config. Ctrl-C ends a run with one line naming the command that continues it
(exit code 130).
"""

from __future__ import annotations

import logging
import math
import sys
import traceback
from pathlib import Path

import hydra
from hydra._internal.utils import _run_hydra, get_args_parser
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from grt.cli._common import CONF_DIR, exit_on_user_error, find_user_error, run_cli
from grt.config import validate
from grt.errors import INTERRUPTED
from grt.runfolder import interrupted, own_config, resume_overrides
from grt.runner import run

log = logging.getLogger("grt.run")


@hydra.main(config_path=CONF_DIR, config_name="run", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns Final Drop (NaN for a failed job of a sweep, which goes on)."""
    if cfg.resume:
        cfg = own_config(cfg)
    try:
        validate(cfg)  # budget ranges, +budget keys, optimizer settings: refused before any simulation
        summary = run(cfg)
    except KeyboardInterrupt:
        log.warning(interrupted(Path(cfg.resume or cfg.paths.output_dir)))
        raise SystemExit(INTERRUPTED) from None
    except Exception as exc:
        if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
            out = Path(cfg.paths.output_dir)  # the job's own folder (never a refused resume's)
            out.mkdir(parents=True, exist_ok=True)
            (out / "error.txt").write_text(traceback.format_exc())
            log.error("job failed (%s: %s); details in %s; the sweep goes on",
                      type(exc).__name__, exc, out / "error.txt")
            return math.nan
        found = find_user_error(exc)
        if found is not None:
            log.error("%s: %s", type(found).__name__, found)
            raise SystemExit(2) from exc
        raise
    return float(summary["final_drop"])


def cli(argv: list[str] | None = None) -> None:
    """``grt-run``: a ``resume=`` is checked, and becomes the run's own command, before Hydra starts.

    The command line is parsed with the parser ``hydra.main`` itself uses, and the parsed arguments (with a
    resume's overrides) go to Hydra's own runner, as ``hydra.main`` hands them over: ``sys.argv`` is left
    as it is.
    """
    parser = get_args_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else list(argv))
    if any("resume=" in arg for arg in args.overrides):
        with exit_on_user_error():
            args.overrides = resume_overrides(args.overrides)
    run_cli(lambda: _run_hydra(args=args, args_parser=parser, task_function=main, config_path=CONF_DIR,
                               config_name="run"))
