"""Kept for old commands: ``python scripts/train_policy.py ...`` is ``python -m grt.train ...`` (:mod:`grt.cli.train`)."""

from grt.cli.train import cli

if __name__ == "__main__":
    cli()
