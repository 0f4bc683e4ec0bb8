"""``python -m grt.setup``: the ``grt-setup`` app (:mod:`grt.cli.setup`)."""

from grt.cli.setup import cli

if __name__ == "__main__":
    cli()
