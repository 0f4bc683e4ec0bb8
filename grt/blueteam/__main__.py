"""``python -m grt.blueteam``: see :mod:`grt.cli.blueteam`."""

from grt.cli.blueteam import cli

if __name__ == "__main__":
    cli()
