"""``python -m grt.deform``: the ``grt-deform`` app (:mod:`grt.cli.deform`)."""

from grt.cli.deform import cli

if __name__ == "__main__":
    cli()
