"""``python -m grt.replay``: the ``grt-replay`` app (:mod:`grt.cli.replay`); the replay itself is :mod:`grt.rerun`."""

from grt.cli.replay import cli

if __name__ == "__main__":
    cli()
