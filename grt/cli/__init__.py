"""GRT's command-line apps, one module each: thin Hydra or argparse shells over library functions.

Every app module ``grt/cli/<name>.py`` exposes ``cli()``, the console script ``grt-<name>`` declared in
``pyproject.toml``; the documented ``python -m grt.<name>`` commands are one-line shims that call it.
Apps sit on top of the layers: they may import any GRT module, no GRT module below imports them.
"""
