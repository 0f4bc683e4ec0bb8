"""``python -m grt.profile``: the ``grt-profile`` app (:mod:`grt.cli.profile`)."""

from grt.cli.profile import cli

if __name__ == "__main__":
    cli()
