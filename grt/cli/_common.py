# TEMPORARY (blueteam branch): the apps helper's grt/cli/_common.py replaces this file at merge.
"""Re-exports the CLI error handling from :mod:`grt.errors` until it moves here."""

from grt.errors import exit_on_user_error, run_cli

__all__ = ["exit_on_user_error", "run_cli"]
