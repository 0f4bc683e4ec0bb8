"""The Hydra callback of every app that writes a run folder (``conf/hydra/default.yaml`` and the apps' root
configs): the folder is claimed before Hydra writes its record there (:func:`grt.runfolder.lock.claim`)."""

from __future__ import annotations

import sys
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from grt.errors import UserError
from grt.runfolder.lock import claim, release
from grt.runfolder.resume import check_in_place


class RunFolderCallback(Callback):
    """Hydra callback of ``grt.run``, ``grt.train``, ``grt.blueteam``, ``grt.evaluate`` and ``grt.select``:
    :func:`grt.runfolder.lock.claim` the run folder before Hydra makes it and writes its record there, so two
    processes never share one (a second ``grt.blueteam resume=DIR`` of a study still running is refused, not
    mixed into it), and refuse a training or study continued in place with other settings
    (:func:`grt.runfolder.resume.check_in_place`). A ``grt.run`` sweep's jobs (new folders each) are locked
    by :func:`grt.runner.run`. Hydra turns a callback's exception into a warning and goes on, so a refusal is
    the apps' one ``error:`` line on stderr here, and exit code 2."""

    def on_run_start(self, config: DictConfig, **kwargs) -> None:
        HydraConfig.instance().set_config(config)  # hydra.run.dir reads ${hydra:runtime.choices...}
        try:
            run_dir = Path(str(config.hydra.run.dir))
        except Exception:  # noqa: BLE001 - e.g. an unknown object in the folder's name: Hydra reports it
            return
        app = str(config.hydra.job.name)
        try:
            claim(run_dir, OmegaConf.select(config, "resume"), f"{app}.log", app)
            try:
                check_in_place(run_dir, OmegaConf.to_container(config, resolve=False), app)
            except UserError:
                release(run_dir)
                raise
        except UserError as exc:
            print(f"error: {exc}", file=sys.stderr, flush=True)
            raise SystemExit(2) from None

    def on_run_end(self, config: DictConfig, **kwargs) -> None:
        release(Path(str(config.hydra.run.dir)))
