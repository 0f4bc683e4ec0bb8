"""What pyproject.toml cannot say: the top-level ``conf/`` ships inside the package as ``grt.conf``.

``conf/`` stays at the top of the repository (Hydra's layout, where a checkout's commands find it); an
installed wheel has it as ``grt/conf``, where :data:`grt.CONF_DIR` finds it, so an installed GRT runs from
any folder. Everything else about the package is in ``pyproject.toml``.
"""

from setuptools import find_namespace_packages, setup

CONF = ["grt.conf", *(f"grt.conf.{group}" for group in find_namespace_packages(where="conf"))]

setup(packages=[*find_namespace_packages(include=["grt", "grt.*"]), *CONF], package_dir={"grt.conf": "conf"})
