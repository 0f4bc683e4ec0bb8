"""``python -m grt.run``: the ``grt-run`` app (:mod:`grt.cli.run`); the run itself is :func:`grt.runner.run`."""

from grt.cli.run import cli

if __name__ == "__main__":
    cli()
