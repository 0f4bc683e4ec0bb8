"""Nothing the user has is overwritten (issue 40): ``grt.deform --out`` over an input or another file, a new
run in a folder holding the user's files, a resume of a finished run, an edited run record, an empty
``resume=``; and the resume command printed for a folder with spaces and non-ASCII letters works when pasted.

The runs are real ``grt.run`` processes with the toy evaluator of ``tests/runner/_toy_run.py`` (no simulator),
one finished run made once for the module and copied for each test.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh

import grt.cli.deform as deform_cli
from grt.objects import get_object
from tests.cli.test_run_faults import RUN, error_line, grt_run, snapshot

ROOT = Path(__file__).resolve().parents[2]


def _in_process(main, argv, capsys) -> tuple[int, str]:
    with pytest.raises(SystemExit) as info:
        main(argv)
    return info.value.code, capsys.readouterr().err


# ------------------------------------------------------------------------------------------- grt.deform

def test_deform_never_writes_over_its_input_and_asks_before_replacing_a_file(tmp_path, capsys):
    """``--out`` naming the input mesh (or a link to it) is refused, ``--overwrite`` or not; an ``--out`` that
    is another existing file needs ``--overwrite``."""
    mesh = tmp_path / "can.obj"
    get_object("can").export(mesh)
    (tmp_path / "h.txt").write_text("0 0 0 0.1\n")
    (tmp_path / "a.txt").write_text("5 0 0 0\n6 0 0 0\n7 0 0 0\n")
    (tmp_path / "link.obj").symlink_to(mesh)
    (tmp_path / "mine.obj").write_text("the user's own file\n")
    before = snapshot(tmp_path)
    targets = ["--handles", str(tmp_path / "h.txt"), "--anchors", str(tmp_path / "a.txt")]
    for out, extra, message in ((mesh, [], "is the input mesh"), (tmp_path / "link.obj", ["--overwrite"],
                                                                    "is the input mesh"),
                                (tmp_path / "mine.obj", [], "already exists; give another --out, or --overwrite")):
        code, err = _in_process(deform_cli.main, [str(mesh), *targets, "--out", str(out), *extra], capsys)
        assert code == 2 and err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert snapshot(tmp_path) == before  # not a byte changed
    assert deform_cli.main([str(mesh), *targets, "--out", str(tmp_path / "mine.obj"), "--overwrite"]) == 0
    assert len(trimesh.load(tmp_path / "mine.obj", process=False).vertices) == len(get_object("can").vertices)


# ------------------------------------------------------------------------------------------------ resume=

@pytest.mark.parametrize("app", ["run", "train", "blueteam"])
def test_an_empty_resume_is_refused_not_a_new_run(app, tmp_path, capsys, monkeypatch):
    """``resume=$RUN`` with ``RUN`` unset reaches the app as ``resume=``: refused before Hydra starts (nothing
    written), not taken for a new run."""
    import importlib

    monkeypatch.chdir(tmp_path)
    cli = importlib.import_module(f"grt.cli.{app}").cli
    code, err = _in_process(cli, ["resume=", f"hydra.run.dir={tmp_path / 'new'}"], capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("error: 'resume=': resume= is empty (an unset shell variable?)") and "resume=DIR" in err
    assert list(tmp_path.iterdir()) == []
