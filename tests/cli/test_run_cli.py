"""``grt-run``'s ``cli()`` hands Hydra a resume's own command without touching ``sys.argv``."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

import grt.cli.run as run_cli
from grt.runfolder.resume import resume_overrides

RELEASE = Path(__file__).resolve().parents[1] / "data" / "run_format1_toy"


def test_a_resume_reaches_hydra_as_the_runs_own_command(tmp_path, monkeypatch):
    """Through Hydra's public entry point: the ``@hydra.main`` app (``main``, config ``run``) reads the run's own
    command as the process's arguments while it runs; they are the caller's again afterwards."""
    run_dir = tmp_path / "run"
    shutil.copytree(RELEASE, run_dir)
    given = ["budget.workers=1", f"resume={run_dir}"]
    seen = {}
    real = run_cli.main
    monkeypatch.setattr(run_cli, "main", lambda: seen.update(argv=list(sys.argv)))
    argv = list(sys.argv)
    run_cli.cli(given)
    assert sys.argv == argv
    assert seen["argv"] == [argv[0], *resume_overrides(given)]
    assert real.__wrapped__.__name__ == "main" and real.__module__ == "grt.cli.run"


def test_a_refused_resume_is_one_line_and_leaves_sys_argv(tmp_path, capsys):
    argv = list(sys.argv)
    with pytest.raises(SystemExit) as info:
        run_cli.cli([f"resume={tmp_path / 'missing'}"])
    assert info.value.code == 2 and sys.argv == argv
    err = capsys.readouterr().err
    assert err.startswith("error: resume=") and "no such folder" in err and err.count("\n") == 1


@pytest.mark.parametrize("command", [
    ["budget=smoke", "selector=all"],
    ["-m", "--config-dir", "/tmp/mine", "selector=heuristic,all", "budget.trials=3"],
    ["--cfg", "job", "--resolve", "--package", "budget", "budget=smoke"],
    ["--info", "searchpath"], ["--info"], ["--help"], ["-h"], ["--hydra-help"], ["-cn", "run", "-cp", "/x", "a=1"],
])
def test_the_command_hydra_gets_is_the_one_given(command, monkeypatch):
    """:func:`grt.cli._common.launch` hands ``@hydra.main`` the command it was given, flags included: Hydra's own
    parser reads the same from it as from the original."""
    from hydra._internal.utils import get_args_parser  # Hydra's parser, to compare with

    from grt.cli._common import launch, parse_command

    seen = {}
    launch(lambda: seen.update(argv=list(sys.argv)), parse_command(command))
    assert vars(get_args_parser().parse_args(seen["argv"][1:])) == vars(get_args_parser().parse_args(command))
