"""GRT: geometric red-teaming of robot manipulation policies.

:data:`CONF_DIR` is GRT's config folder, wherever GRT runs from: ``grt/conf`` inside an installed wheel
(``pip install .`` ships the repository's top-level ``conf/`` as the package ``grt.conf``, ``setup.py``),
the repository's ``conf/`` in a checkout or an editable install (``pip install -e .``).
"""

from pathlib import Path as _Path

__version__ = "0.1.0"

_HERE = _Path(__file__).resolve().parent
CONF_DIR = str(_HERE / "conf" if (_HERE / "conf").is_dir() else _HERE.parent / "conf")
