"""The record of an experiments/ folder: its markdown tables and the README blocks generated from them."""

from __future__ import annotations

import json
import shlex
import shutil
from pathlib import Path

import pytest

from grt.cli.report import main
from grt.report.tables import BLOCK, ReportError, render, update_readme, update_readmes

ROOT = Path(__file__).resolve().parents[2]
DRAWER = ROOT / "experiments" / "table1_drawer"


@pytest.fixture
def table(tmp_path):
    """A copy of a committed table folder with two summaries and a blue-team table."""
    folder = tmp_path / "table1_drawer"
    shutil.copytree(DRAWER, folder)
    (folder / "table3_x.json").write_text(json.dumps([{
        "policy": "insertion_state", "geometry": "it4_c6", "fine_tune": "it4_c6", "orig": 12 / 32, "blue": 30 / 32,
        "nominal_before": 31 / 32, "nominal_after": 30 / 32, "heldout_before": 0.3125, "heldout_after": 0.51,
        "red_team_score": 0.25, "trials": 32}]))
    return folder


def test_markdown_of_a_folder(table, capsys):
    text = render(table, records=True)
    assert "| drawer | drawer_handle | drawer_state | manual + topdm + SS | 0.06 |" in text
    assert "| 47.1 |" in text and "Mean per method" in text
    assert "| insertion_state | it4_c6 | it4_c6 | 37.5 | 93.8 | 96.9 | 93.8 | 31.2 | 51.0 |" in text
    assert "| `summary_manual_ss.json` | c5a21cbef | no | 8 x 8 x 8 | 0.06 | 0.004 | - |" in text
    main([str(table), "--markdown"])
    assert capsys.readouterr().out.strip() == render(table).strip()


def test_a_continuous_blue_team_score_is_not_a_percentage(tmp_path):
    rows = [{"policy": "drawer_state", "geometry": "it2_c7", "orig": 0.1758, "blue": 0.1479, "nominal_before": 0.3821,
             "nominal_after": 0.3821, "heldout_before": 0.2058, "heldout_after": 0.1894, "trials": 32}]
    (tmp_path / "table3.json").write_text(json.dumps(rows))
    assert "| 0.176 | 0.148 | 0.382 | 0.382 | 0.206 | 0.189 |" in render(tmp_path)


def test_readme_block_update_is_idempotent(table):
    readme = table / "README.md"
    readme.write_text("# T\n\nbefore\n\n<!-- grt.report . --records -->\nstale\n<!-- /grt.report -->\n\nafter\n")
    assert update_readme(readme) is True
    first = readme.read_text()
    assert first.startswith("# T\n\nbefore\n\n<!-- grt.report . --records -->\n| task |")
    assert first.endswith("<!-- /grt.report -->\n\nafter\n") and "stale" not in first
    assert render(table, records=True) in first
    assert update_readme(readme) is False and readme.read_text() == first
    assert update_readmes(table.parent) == []


def test_update_readmes_from_the_command_line(table, capsys):
    (table / "README.md").write_text("<!-- grt.report . -->\n<!-- /grt.report -->\n")
    main([str(table.parent), "--update-readmes"])
    assert f"updated {table / 'README.md'}" in capsys.readouterr().out
    main([str(table.parent), "--update-readmes"])
    assert "up to date" in capsys.readouterr().out


def test_a_block_naming_nothing_is_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    readme = tmp_path / "README.md"
    readme.write_text("<!-- grt.report empty -->\n<!-- /grt.report -->\n")
    with pytest.raises(ReportError, match="no summary.json"):
        update_readme(readme)
    readme.write_text("<!-- grt.report empty --wide -->\n<!-- /grt.report -->\n")
    with pytest.raises(ReportError, match="--wide"):
        update_readme(readme)


def test_committed_readmes_are_up_to_date():
    """Every generated table under experiments/ matches its files (regenerate: grt.report experiments --update-readmes)."""
    for readme in sorted((ROOT / "experiments").rglob("README.md")):
        for m in BLOCK.finditer(readme.read_text()):
            args = shlex.split(m.group("args"))
            assert m.group("body") == render(readme.parent / args[0], records="--records" in args) + "\n", readme


def test_a_kept_run_record_is_not_an_unfinished_job(tmp_path, capsys):
    """experiments/ keeps a run's record as summary_<name>.json beside its run_config.yaml: a finished run, not
    a job that never wrote summary.json; a record without any summary still is one."""
    kept, stopped = tmp_path / "kept", tmp_path / "stopped"
    kept.mkdir()
    stopped.mkdir()
    shutil.copyfile(DRAWER / "summary_manual_ss.json", kept / "summary_kept.json")
    for folder in (kept, stopped):
        (folder / "run_config.yaml").write_text("task: {}\n")
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "1 unfinished job(s)" in out and f"- {stopped}" in out and f"- {kept}\n" not in out + "\n"
