"""``python -m grt.train``: see :mod:`grt.cli.train`."""

from grt.cli.train import cli

if __name__ == "__main__":
    cli()
