"""``python -m grt.blueteam run=<red-team run folder>`` (``grt-blueteam``): fine-tune the run's policy on
its CrashShapes (paper Table 3); a Hydra app.

    python -m grt.blueteam run=outputs/insertion/usb_plug/insertion_state/manual-topdm/<time>
    python -m grt.blueteam resume=outputs/blueteam/<time>                      # continue a killed study
    python -m grt.blueteam resume=outputs/blueteam/<time> workers=8 blueteam.rered.enabled=false
    python -m grt.blueteam resume=outputs/blueteam/<time> blueteam.iterations=300 blueteam.val_patience=10

The work and the folder's files: :func:`grt.blueteam.study.blueteam`, which reads the study's settings as a
:class:`grt.blueteam.spec.StudySpec` (:func:`study_spec`, made and checked here before torch is imported) and
runs the re-red-team through :func:`rered_run`. The folder is made and locked before
Hydra writes there (:class:`grt.cli.callbacks.RunFolderCallback`): a second study in it (the same ``resume=``) is
refused with one line naming the first's PID, exit code 2.

``resume=DIR`` alone is the whole command to continue a study, with its own config, ``run=`` included:
Hydra's record of its start, ``DIR/.hydra/config.yaml`` (:func:`grt.runfolder.resume.own_study_config`). :func:`cli`
checks DIR and the command before Hydra starts and hands Hydra the study's own overrides: only the keys of
:data:`grt.runfolder.resume.STUDY_FREE` may be given with it (``workers``, ``blueteam.iterations`` to fine-tune
longer, or shorter, a study not yet finished — give it again on each later resume, the record keeps the
start's —, ``blueteam.val_patience`` likewise, ``blueteam.rered.enabled``, ``paths.cache_dir``, ``hydra.*``), and ``evaluator=sim|ray`` and the evaluator's
keys but its collision ones; any other override that would change the study is one ``error:`` line naming
the key, the study's value and the given one (exit code 2), nothing written. A folder that is not a study (a
red-team run's among them) is refused the same way. Hydra's files of a resume go to ``DIR/.hydra/resume``, so
``DIR/.hydra`` stays the record of the start. A folder whose ``.hydra`` a resume rewrote (before this was so)
goes on with that record, the config it last ran with, and a line saying so.
"""

from __future__ import annotations

import functools
import logging
import sys
from collections.abc import Mapping
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from grt.blueteam.spec import BlueTeamError, StudySpec
from grt.cli._common import CONF_DIR, exit_on_user_error, find_user_error, resumable_cli
from grt.config import plain, validate  # also registers schemas and resolvers
from grt.config.records import ConfigView
from grt.plan import RunPlan
from grt.runfolder.lock import discard_new
from grt.runfolder.record import STUDY_RECORD, ResumeError, resume_or
from grt.runfolder.resume import STUDY, SavedRun, own_study_config

log = logging.getLogger("grt.blueteam")


@hydra.main(config_path=CONF_DIR, config_name="blueteam", version_base="1.3")
def main(cfg: DictConfig) -> None:
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    in_place = bool(cfg.resume) and Path(cfg.resume).resolve() == out_dir.resolve()
    with exit_on_user_error():
        try:
            if not cfg.resume:  # before torch and the simulator are imported: a refused command is quick
                validate(cfg)  # the evaluator's class imports and takes its keys, nothing unread
            if cfg.resume:  # also when hydra.run.dir is given, which the resume_or resolver then never sees
                resume = Path(resume_or(cfg.resume, ""))
                if not in_place:
                    raise ResumeError(f"resume={cfg.resume} with hydra.run.dir={out_dir}: a study goes on in its "
                                      f"own folder; give resume={cfg.resume} alone")
                cfg = resumed_config(cfg, resume)
            if cfg.run is None:
                raise BlueTeamError("give the red-team run to blue-team: python -m grt.blueteam run=<run folder>")
            if cfg.resume:
                validate(cfg)  # the study's own config: its classes must still import
            spec = study_spec(cfg)
            from grt.blueteam.study import blueteam  # torch and the simulator: not for a refused command

            result = blueteam(spec, out_dir, red_team=functools.partial(rered_run, evaluator=spec.evaluator))
        except Exception as exc:
            found = find_user_error(exc)
            if found is None or in_place:  # a study's own folder keeps what it holds
                raise
            removed = discard_new(out_dir)  # refused before it saved anything: no folder left behind
            print(f"error: {found}" + (f" ({removed})" if removed else ""), file=sys.stderr)
            raise SystemExit(2) from None
    print((out_dir / "table3.md").read_text())
    if "rered" in result:
        r = result["rered"]
        print(f"re-red-team: Final Drop {r['before']['final_drop']} -> {r['after']['final_drop']}, "
              f"Iter@50% {r['before']['iter_at_50']} -> {r['after']['iter_at_50']}")
    print(f"files in {out_dir}")


def resumed_config(cfg: DictConfig, out_dir: Path) -> DictConfig:
    """The config a resume of the study in ``out_dir`` goes on with: its record, with the free keys of this
    command (:func:`grt.runfolder.resume.own_study_config`).

    Says in one line (console and ``blueteam.log``) when the record is an earlier resume's (a folder whose
    ``.hydra`` a resume rewrote, before ``grt.blueteam`` kept the start's record): the study goes on with
    that record, the config it last ran with, as its files were last written. And when a
    ``blueteam.iterations`` given would train longer a fine-tune that is finished (``policy.pt`` there): it
    is not trained again.
    """
    overrides = list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []
    own = OmegaConf.create(own_study_config(str(cfg.resume), plain(cfg), overrides))
    saved = SavedRun.study(Path(cfg.resume))
    if not saved.started:
        log.warning("%s is the record of an earlier resume (made before grt.blueteam kept the record of a "
                    "study's start): the study goes on with that record (run=%s)", Path(cfg.resume) / STUDY_RECORD,
                    own.run)
    recorded = ConfigView(saved.config).get("blueteam.iterations")
    if (out_dir / "policy.pt").exists() and recorded is not None and int(own.blueteam.iterations) != int(recorded):
        log.warning("blueteam.iterations=%s: the fine-tune is finished (policy.pt in %s), it is not trained again",
                    own.blueteam.iterations, out_dir)
    return own


def study_spec(cfg: DictConfig) -> StudySpec:
    """The study's settings of the app's config, parsed and checked once (:meth:`StudySpec.of`).

    Raises:
        BlueTeamError: a setting out of range, in one line naming it.
    """
    swap = cfg.get("swap_check")
    return StudySpec.of(plain(cfg.blueteam), run=cfg.run, workers=cfg.workers, cache_dir=cfg.paths.cache_dir,
                        evaluator=plain(cfg.evaluator), swap_check=plain(swap) if swap is not None else None)


#: evaluator keys a candidate's trials depend on (its collision parts): a re-red-team keeps the run's
SEARCH_EVALUATOR_KEYS = ("collision", "coacd", "max_hull_vertices")


def rered_config(run_config: dict, checkpoint: Path, out: Path, evaluator: Mapping | None = None) -> DictConfig:
    """The re-red-team's config: the red-team run's own (``run_config``, as its folder keeps it: budget, seed,
    search), the fine-tuned policy, a new folder, and the blue-team's evaluator (``evaluator``, the app's
    ``evaluator`` node, plain: its backend, e.g. a Ray cluster, and its workers; ``None`` keeps the run's), but the
    run's collision settings (:data:`SEARCH_EVALUATOR_KEYS`): neither the backend nor the number of workers
    changes a result."""
    cfg = OmegaConf.create(dict(run_config))  # a copy: the run's own config stays as it is
    cfg.policy.checkpoint = str(checkpoint)
    cfg.paths.output_dir = str(out)
    cfg.resume = None
    if evaluator is not None:
        ev = dict(evaluator)
        own = OmegaConf.to_container(cfg.evaluator, resolve=False)
        ev.update({k: own[k] for k in SEARCH_EVALUATOR_KEYS if k in own})
        cfg.evaluator = ev
        cfg.budget.workers = ev["workers"]
    return cfg


def rered_run(run: RunPlan, checkpoint: Path, out: Path, evaluator: Mapping | None = None) -> dict:
    """The study's re-red-team (:data:`grt.blueteam.study.RedTeam`): GRT's red-team run (:func:`grt.runner.run`)
    of :func:`rered_config` of the run's own config; returns its summary."""
    from grt.runner import run as red_team

    return red_team(rered_config(run.config, checkpoint, out, evaluator))


def cli(argv: list[str] | None = None) -> None:
    """The console script ``grt-blueteam``: a ``resume=`` becomes the folder's own command before Hydra starts."""
    resumable_cli(main, STUDY, argv)
