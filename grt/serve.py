"""``python -m grt.serve``: the ``grt-serve`` app (:mod:`grt.cli.serve`)."""

from grt.cli.serve import cli

if __name__ == "__main__":
    cli()
