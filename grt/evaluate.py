"""``python -m grt.evaluate``: the ``grt-evaluate`` app (:mod:`grt.cli.evaluate`)."""

from grt.cli.evaluate import cli

if __name__ == "__main__":
    cli()
