"""``python -m grt.calibrate``: the ``grt-calibrate`` app (:mod:`grt.cli.calibrate`)."""

from grt.cli.calibrate import cli

if __name__ == "__main__":
    cli()
