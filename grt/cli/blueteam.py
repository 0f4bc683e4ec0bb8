"""``python -m grt.blueteam run=<red-team run folder>`` (``grt-blueteam``): fine-tune the run's policy on
its CrashShapes (paper Table 3); a Hydra app.

    python -m grt.blueteam run=outputs/insertion/usb_plug/manual-topdm/<time>
    python -m grt.blueteam run=... resume=outputs/blueteam/<time>   # continue a killed fine-tune

The work and the folder's files: :func:`grt.blueteam.study.blueteam`. The folder is made and locked before
Hydra writes there (:class:`grt.runfolder.RunFolderCallback`): a second study in it (the same ``resume=``) is
refused with one line naming the first's PID, exit code 2.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

import grt.config  # noqa: F401 - schemas and resolvers
import grt.runfolder  # noqa: F401 - registers the resume_or resolver
from grt.blueteam.core import BlueTeamError
from grt.blueteam.study import blueteam
from grt.cli._common import CONF_DIR, exit_on_user_error, run_cli
from grt.runner import run as red_team


@hydra.main(config_path=CONF_DIR, config_name="blueteam", version_base="1.3")
def main(cfg: DictConfig) -> None:
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    with exit_on_user_error():
        if cfg.run is None:
            raise BlueTeamError("give the red-team run to blue-team: python -m grt.blueteam run=<run folder>")
        result = blueteam(cfg, out_dir, red_team=red_team)
    print((out_dir / "table3.md").read_text())
    if "rered" in result:
        r = result["rered"]
        print(f"re-red-team: Final Drop {r['before']['final_drop']} -> {r['after']['final_drop']}, "
              f"Iter@50% {r['before']['iter_at_50']} -> {r['after']['iter_at_50']}")
    print(f"files in {out_dir}")


def cli() -> None:
    """The console script ``grt-blueteam``."""
    run_cli(main)
