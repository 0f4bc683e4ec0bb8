"""``grt-run``'s ``cli()`` hands Hydra a resume's own command without touching ``sys.argv``."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

import grt.cli.run as run_cli
from grt.runfolder import resume_overrides

RELEASE = Path(__file__).resolve().parents[1] / "data" / "run_format1_toy"


def test_a_resume_reaches_hydra_as_the_runs_own_command(tmp_path, monkeypatch):
    run_dir = tmp_path / "run"
    shutil.copytree(RELEASE, run_dir)
    given = ["budget.workers=1", f"resume={run_dir}"]
    seen = {}
    monkeypatch.setattr(run_cli, "_run_hydra", lambda args, **kw: seen.update(overrides=args.overrides, **kw))
    argv = list(sys.argv)
    run_cli.cli(given)
    assert sys.argv == argv
    assert seen["overrides"] == resume_overrides(given) and seen["config_name"] == "run"
    assert seen["task_function"] is run_cli.main


def test_a_refused_resume_is_one_line_and_leaves_sys_argv(tmp_path, capsys):
    argv = list(sys.argv)
    with pytest.raises(SystemExit) as info:
        run_cli.cli([f"resume={tmp_path / 'missing'}"])
    assert info.value.code == 2 and sys.argv == argv
    err = capsys.readouterr().err
    assert err.startswith("error: resume=") and "no such folder" in err and err.count("\n") == 1
