"""GRT: geometric red-teaming of robot manipulation policies.

:data:`CONF_DIR` is GRT's config folder, wherever GRT runs from: ``grt/conf`` inside an installed wheel
(``pip install .`` ships the repository's top-level ``conf/`` as the package ``grt.conf``, ``setup.py``),
the repository's ``conf/`` in a checkout or an editable install (``pip install -e .``).
:func:`motionplanning_dir` is where the workers of ManiSkill's motion planners find their numpy 1.26
(``python -m grt.setup motionplanning`` puts it there).
"""

import os as _os
from pathlib import Path as _Path

__version__ = "0.1.0"

_HERE = _Path(__file__).resolve().parent
CONF_DIR = str(_HERE / "conf" if (_HERE / "conf").is_dir() else _HERE.parent / "conf")
CHECKOUT = not (_HERE / "conf").is_dir() and (_HERE.parent / "pyproject.toml").is_file()  # not a wheel


def motionplanning_dir() -> str:
    """The folder of numpy 1.26 for the motion planners' workers: ``$GRT_MOTIONPLANNING_DIR``; in a checkout its
    ``.motionplanning/`` (``make motionplanning``); installed, ``grt/motionplanning`` in the user's data folder
    (``$XDG_DATA_HOME``, else ``~/.local/share``)."""
    if _os.environ.get("GRT_MOTIONPLANNING_DIR"):
        return _os.environ["GRT_MOTIONPLANNING_DIR"]
    if CHECKOUT:
        return str(_HERE.parent / ".motionplanning")
    data = _os.environ.get("XDG_DATA_HOME") or str(_Path.home() / ".local" / "share")
    return str(_Path(data) / "grt" / "motionplanning")
