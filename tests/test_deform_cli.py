"""``python -m grt.deform`` end to end, and its errors for bad target files."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import trimesh

from grt.cli.deform import TargetFileError, read_targets
from grt.objects import get_object


def _write(path, idx, pos):
    path.write_text("".join(f"{i} {x} {y} {z}\n" for i, (x, y, z) in zip(idx, pos, strict=False)))


def test_cli_deforms_builtin_object(tmp_path):
    m = get_object("can")
    v = m.vertices
    h = np.argsort(-v[:, 2])[:2]
    a = np.flatnonzero(v[:, 2] < 0.005)
    _write(tmp_path / "h.txt", h, v[h] + [0, 0, 0.01])
    _write(tmp_path / "a.txt", a, v[a])
    out = tmp_path / "out.obj"
    r = subprocess.run([sys.executable, "-m", "grt.deform", "can", "--handles", str(tmp_path / "h.txt"),
                        "--anchors", str(tmp_path / "a.txt"), "--out", str(out), "--no-align"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "residual" in r.stdout and str(out) in r.stdout
    res = trimesh.load(out, process=False)
    assert len(res.vertices) == len(v)
    np.testing.assert_allclose(res.vertices[h], v[h] + [0, 0, 0.01], atol=1e-6)


def test_cli_reports_bad_file(tmp_path):
    (tmp_path / "h.txt").write_text("0 0 0 0\n1 oops 0 0\n")
    (tmp_path / "a.txt").write_text("5 0 0 0\n")
    r = subprocess.run([sys.executable, "-m", "grt.deform", "can", "--handles", str(tmp_path / "h.txt"),
                        "--anchors", str(tmp_path / "a.txt"), "--out", str(tmp_path / "o.obj")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "h.txt:2" in r.stderr


@pytest.mark.parametrize("text, match", [("", "empty"), ("1 2 3\n", ":1"), ("# c\n\n1 0 0 nan\n", ":3.*NaN"),
                                         ("1.5 0 0 0\n", ":1")])
def test_read_targets_errors(tmp_path, text, match):
    p = tmp_path / "t.txt"
    p.write_text(text)
    with pytest.raises(TargetFileError, match=match):
        read_targets(p)


def test_read_targets_missing_file(tmp_path):
    with pytest.raises(TargetFileError, match="not found"):
        read_targets(tmp_path / "nope.txt")
