"""Nothing the user has is replaced unless they ask: an existing output file of ``grt.report`` or ``grt.replay``
needs ``--overwrite`` (``grt.train resume=`` of a finished training: ``tests/cli/test_train_resume.py``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.cli.test_run_faults import snapshot

ROOT = Path(__file__).resolve().parents[2]


def _in_process(main, argv, capsys) -> tuple[int, str]:
    with pytest.raises(SystemExit) as info:
        main(argv)
    return info.value.code, capsys.readouterr().err


@pytest.mark.parametrize("flag", ["--csv", "--search-plot"])
def test_report_asks_before_replacing_a_file(toy_run, tmp_path, capsys, flag):
    import grt.cli.report as report_cli

    mine = tmp_path / ("rows.csv" if flag == "--csv" else "plot.png")
    mine.write_text("the user's own file\n")
    code, err = _in_process(report_cli.main, [str(toy_run), flag, str(mine)], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"error: {flag} {mine} already exists; give another {flag}, or --overwrite to replace it")
    assert mine.read_text() == "the user's own file\n"
    assert report_cli.main([str(toy_run), flag, str(mine), "--overwrite"]) is None
    assert mine.read_bytes() != b"the user's own file\n"


def test_replay_asks_before_replacing_a_video(toy_run, tmp_path):
    mine = tmp_path / "clip.mp4"
    mine.write_bytes(b"the user's own video")
    before = snapshot(toy_run)
    proc = subprocess.run([sys.executable, "-m", "grt.replay", str(toy_run), f"video={mine}"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith(f"error: video={mine} already exists; give another video=PATH.mp4, or --overwrite")
    assert mine.read_bytes() == b"the user's own video" and snapshot(toy_run) == before



def test_a_new_run_inside_a_runs_folder_is_refused_and_changes_nothing(toy_run):
    """``hydra.run.dir=RUN/inner`` ran, and ``grt.report RUN`` then averaged the two runs."""
    from tests.cli.test_run_faults import RUN, error_line, grt_run

    before = snapshot(toy_run)
    res = grt_run(*RUN, f"hydra.run.dir={toy_run / 'inner'}")
    assert res.returncode == 2, res.stderr[-3000:]
    line = error_line(res.stderr, res.stdout)
    assert line.startswith(f"error: {toy_run / 'inner'} is inside the red-team run {toy_run.resolve()}: a new "
                           "python -m grt.run there would mix its files"), line
    assert snapshot(toy_run) == before and not (toy_run / "inner").exists()
