"""``python -m grt.objects``: the ``grt-objects`` app (:mod:`grt.cli.objects`)."""

from grt.cli.objects import cli

if __name__ == "__main__":
    cli()
