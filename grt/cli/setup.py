"""``python -m grt.setup WHAT`` (``grt-setup``): install what an optional policy needs, for an installed GRT too.

``motionplanning``: numpy 1.26 into a folder of its own (``--dir``; default :func:`grt.motionplanning_dir`: a
checkout's ``.motionplanning/``, an installed GRT's ``~/.local/share/grt/motionplanning``), for the simulator
workers of ManiSkill's motion planners (``policy=motion_planner``: mplib crashes under numpy 2), and mplib
0.1.1 into this environment if it is missing; then checks that both import together.

``cgn``: Contact-GraspNet's pretrained weights (``policy=contact_graspnet``), the ``cgn-pytorch`` wheel
installed without its dependencies (it pins years-old exact versions of torch, numpy, scipy and trimesh that
GRT's cannot share, which is why it is no ``pip install grt[cgn]`` extra; GRT reads only its weights file).

Each is idempotent (a second run says it is there) and uses this Python's pip and package index.
"""

from __future__ import annotations

import importlib
import importlib.util
import subprocess
import sys
from pathlib import Path

from grt import motionplanning_dir
from grt.cli._common import AppParser, exit_on_user_error
from grt.errors import UserError

MP_NUMPY = "numpy==1.26.4"
MPLIB = "mplib==0.1.1"
CGN = "cgn-pytorch==0.4.3"


class SetupError(UserError):
    """A set-up step that failed (pip's last line and what to do)."""


def _pip(*args: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "pip", "install", "-q", *args], capture_output=True, text=True)
    if proc.returncode != 0:
        last = next((line for line in reversed(proc.stderr.splitlines()) if line.strip()), "no output")
        raise SetupError(f"pip install {' '.join(args)} failed ({last.strip()}); check that this machine reaches "
                         "the package index (pip config list), then run this again")


def motionplanning(folder: Path) -> str:
    """Put numpy 1.26 in ``folder`` (mplib into this environment if missing); returns what was done."""
    stamp = folder / ".grt-stamp"
    done = stamp.is_file() and stamp.read_text().strip() == MP_NUMPY
    if not done:
        tmp = folder.with_name(folder.name + ".tmp")
        subprocess.run(["rm", "-rf", str(tmp)], check=True)
        _pip("--target", str(tmp), "--no-deps", MP_NUMPY)
        subprocess.run(["rm", "-rf", str(folder)], check=True)
        folder.parent.mkdir(parents=True, exist_ok=True)
        tmp.rename(folder)
        stamp.write_text(MP_NUMPY + "\n")
    if importlib.util.find_spec("mplib") is None:
        _pip(MPLIB)
    check = subprocess.run([sys.executable, "-c", "import numpy, mplib; print(numpy.__version__)"],
                           capture_output=True, text=True, env={"PYTHONPATH": str(folder), "PATH": "/usr/bin:/bin"})
    if check.returncode != 0 or check.stdout.strip() != MP_NUMPY.split("==")[1]:
        raise SetupError(f"numpy and mplib do not import together from {folder} ({check.stderr.strip()[-200:]}); "
                         f"remove the folder and run python -m grt.setup motionplanning again")
    return (f"{MP_NUMPY} {'was already' if done else 'is now'} in {folder}, mplib beside it: policy=motion_planner "
            f"runs ({'paths.motionplanning' if str(folder) == motionplanning_dir() else 'give paths.motionplanning'}"
            f"={folder})")


def cgn() -> str:
    """Install Contact-GraspNet's weights (the cgn-pytorch wheel, without its pinned dependencies)."""
    from grt.policies.cgn_net import CGNWeightsError, checkpoint_path

    try:
        return f"Contact-GraspNet's weights are already installed ({checkpoint_path()})"
    except CGNWeightsError:
        _pip("--no-deps", CGN)
    importlib.invalidate_caches()
    return f"Contact-GraspNet's weights are installed ({checkpoint_path()}): policy=contact_graspnet runs"


def main(argv: list[str] | None = None) -> None:
    ap = AppParser("setup", description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("motionplanning", "cgn"), help="what to set up")
    ap.add_argument("--dir", type=Path, default=None,
                    help=f"motionplanning: the folder for numpy 1.26 (default: {motionplanning_dir()})")
    args = ap.parse_args(argv)
    with exit_on_user_error():
        if args.what == "motionplanning":
            print(motionplanning((args.dir or Path(motionplanning_dir())).expanduser().resolve()))
        else:
            print(cgn())


def cli() -> None:
    """Console script ``grt-setup``."""
    main()
