"""``python -m grt.select``: the ``grt-select`` app (:mod:`grt.cli.select`)."""

from grt.cli.select import cli

if __name__ == "__main__":
    cli()
