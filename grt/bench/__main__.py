"""``python -m grt.bench``: the ``grt-bench`` app (:mod:`grt.cli.bench`)."""

from grt.cli.bench import cli

if __name__ == "__main__":
    cli()
