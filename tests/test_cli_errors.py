"""Every user mistake in GRT's CLIs is one ``error:`` line and exit code 2, Ctrl-C 130; no traceback.

A few cases per CLI run in a subprocess (what the user sees); the rest call ``main(argv)`` in process.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

import grt.cli.bench as bench_cli
import grt.cli.deform as deform_cli
import grt.cli.report as report_cli
from grt.cli._common import exit_on_user_error
from grt.errors import INTERRUPTED

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def readonly(tmp_path):
    """A folder this process cannot write into (chmod 555; ``/sys`` when running as root)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    for candidate in (folder, Path("/sys")):
        try:
            (candidate / "probe").write_text("x")
            (candidate / "probe").unlink()
        except OSError:
            yield candidate
            break
    else:
        pytest.skip("no read-only folder available")
    folder.chmod(0o755)


@pytest.fixture
def files(tmp_path):
    """Handle/anchor target files for the can, a corrupt mesh, and a run folder with a broken summary."""
    (tmp_path / "h.txt").write_text("0 0 0 0.1\n")
    (tmp_path / "a.txt").write_text("5 0 0 0\n6 0 0 0\n7 0 0 0\n")
    (tmp_path / "bad.obj").write_text("this is not a mesh\n")
    (tmp_path / "broken" / "run").mkdir(parents=True)
    (tmp_path / "broken" / "run" / "summary.json").write_text('{"task": "grasp", "obj')
    (tmp_path / "empty").mkdir()
    return tmp_path


def _check(proc: subprocess.CompletedProcess, code: int, message: str) -> None:
    out = proc.stdout + proc.stderr
    assert proc.returncode == code, out
    assert "Traceback" not in out, out
    errors = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and errors[0].startswith("error: "), proc.stderr
    assert message in errors[0], errors[0]


# (module, arguments with {tmp} and {ro} for the tmp and read-only folders, text expected in the error line)
SUBPROCESS_CASES = [
    ("grt.select", ["object=no_such_thing", "hydra.run.dir={tmp}/s1"], "unknown object 'no_such_thing'"),
    ("grt.select", ["selector=nope", "hydra.run.dir={tmp}/s3"], "Could not find 'selector/nope'"),
    ("grt.select", ["object=can", "hydra.run.dir={ro}/run"], "cannot write"),
    ("grt.evaluate", ["+budget.popsize=3", "hydra.run.dir={tmp}/e1"], "budget.popsize is not a budget"),
    ("grt.evaluate", ["budget.trials=0", "hydra.run.dir={tmp}/e2"], "budget.trials=0 is out of range"),
    ("grt.deform", ["can", "--handles", "{tmp}/h.txt", "--anchors", "{tmp}/a.txt", "--out", "{tmp}/x.xyz"],
     "unsupported format '.xyz'"),
    ("grt.report", ["{tmp}/nowhere"], "does not exist"),
    ("grt.bench", ["nosuch"], "unknown benchmark 'nosuch'"),
    ("grt.bench", ["insertion", "--policy", "nope"], "Could not find 'policy/nope'"),
]


@pytest.mark.parametrize(("module", "args", "message"), SUBPROCESS_CASES,
                         ids=[f"{m}-{i}" for i, (m, _, _) in enumerate(SUBPROCESS_CASES)])
def test_cli_user_error_is_one_line_and_exit_2(module, args, message, files, readonly):
    args = [a.format(tmp=files, ro=readonly) for a in args]
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    proc = subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=180, env=env)
    _check(proc, 2, message)


def _in_process(main, argv, capsys) -> tuple[int, str]:
    with pytest.raises(SystemExit) as info:
        main(argv)
    return info.value.code, capsys.readouterr().err


@pytest.mark.parametrize(("argv", "message"), [
    (["nosuch", "--out", "{tmp}/o.obj"], "unknown object 'nosuch'"),
    (["{tmp}/missing.obj", "--out", "{tmp}/o.obj"], "mesh file not found"),
    (["{tmp}/bad.obj", "--out", "{tmp}/o.obj"], "bad.obj"),
    (["can", "--out", "{tmp}/o"], "no file extension"),
    (["can", "--out", "{tmp}/no/folder/o.obj"], "does not exist; create it (mkdir -p"),
    (["can", "--out", "{tmp}/h.txt/o.obj"], "is a file, not a folder"),
    (["can", "--out", "{tmp}"], "that is a folder; give a file name in it"),
    (["can", "--handles", "{tmp}/missing.txt", "--out", "{tmp}/o.obj"], "missing.txt: file not found"),
    (["can", "--handles", "{tmp}/a.txt", "--out", "{tmp}/o.obj"], "both handle and anchor"),
    (["can", "--lam", "0", "--out", "{tmp}/o.obj"], "lam must be > 0"),
])
def test_deform_mistakes(argv, message, files, capsys):
    argv = [a.format(tmp=files) for a in argv]
    if "--handles" not in argv:
        argv += ["--handles", f"{files}/h.txt"]
    argv += ["--anchors", f"{files}/a.txt"]
    code, err = _in_process(deform_cli.main, argv, capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not (files / "o.obj").exists()


def test_deform_writes_the_file_whole(files, capsys):
    assert deform_cli.main(["can", "--handles", f"{files}/h.txt", "--anchors", f"{files}/a.txt",
                            "--out", f"{files}/o.ply"]) == 0
    assert (files / "o.ply").stat().st_size > 0
    assert [p.name for p in files.iterdir() if ".tmp" in p.name] == []


def _summary(folder: Path, **extra) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "summary.json").write_text(json.dumps({
        "task": "grasp", "object": "mug", "selector": "heuristic", "optimizer": "topdm", "s0": 0.9,
        "best_score": 0.3, "final_drop": 0.66, "delta_complexity": 0.01, "iter_at_50": 3, "reached_50": True,
        "auc": 2.0, "evaluations": 11, "wall_s": 5.0, **extra}))


@pytest.mark.parametrize(("argv", "message"), [
    (["{tmp}/nowhere"], "does not exist"),
    (["{tmp}/empty"], "no summary.json (or summary_<name>.json) under"),
    (["{tmp}/h.txt"], "is a file; give a run folder"),
    (["{tmp}/broken"], "summary.json: cannot read it"),
    (["{tmp}/other"], "not a GRT run summary (no task"),
    (["{tmp}/good", "--csv", "{tmp}/t.txt"], "unsupported format '.txt'"),
    (["{tmp}/good", "--csv", "{tmp}/no/t.csv"], "does not exist"),
])
def test_report_mistakes(argv, message, files, capsys):
    _summary(files / "good" / "run")
    (files / "other").mkdir()
    (files / "other" / "summary.json").write_text("[1, 2]")
    code, err = _in_process(report_cli.main, [a.format(tmp=files) for a in argv], capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1 and message in err, err


def test_deform_into_readonly_folder(files, readonly, capsys):
    argv = ["can", "--handles", f"{files}/h.txt", "--anchors", f"{files}/a.txt", "--out", f"{readonly}/o.obj"]
    code, err = _in_process(deform_cli.main, argv, capsys)
    assert code == 2 and err.startswith("error: cannot write") and "--out PATH" in err, err


def test_report_csv_into_readonly_folder(files, readonly, capsys):
    _summary(files / "good" / "run")
    code, err = _in_process(report_cli.main, [str(files / "good"), "--csv", str(readonly / "t.csv")], capsys)
    assert code == 2 and err.startswith("error: cannot write") and "--csv PATH" in err, err


def _interrupt(*_args, **_kwargs):
    raise KeyboardInterrupt


def test_ctrl_c_is_one_line_and_exit_130(files, monkeypatch, capsys):
    monkeypatch.setattr(deform_cli, "load_mesh", _interrupt)
    monkeypatch.setattr(report_cli, "collect", _interrupt)
    monkeypatch.setattr(bench_cli, "importlib", SimpleNamespace(import_module=lambda name: SimpleNamespace(
        main=_interrupt)))
    calls = [(deform_cli.main, ["can", "--handles", "h", "--anchors", "a", "--out", f"{files}/o.obj"]),
             (report_cli.main, [str(files)]), (bench_cli.main, ["deform"])]
    for main, argv in calls:
        code, err = _in_process(main, argv, capsys)
        assert code == INTERRUPTED and err == "interrupted (Ctrl-C)\n", (main, err)
    with pytest.raises(SystemExit) as info, exit_on_user_error():
        raise KeyboardInterrupt  # what grt.select's and grt.evaluate's apps run under
    assert info.value.code == INTERRUPTED


def test_select_writes_into_hydra_run_dir(files):
    mesh = files / "ball.stl"
    trimesh.creation.icosphere(subdivisions=2, radius=0.04).export(mesh)
    out = files / "chosen"
    proc = subprocess.run([sys.executable, "-m", "grt.select", f"object={mesh}", "selector.k=4",
                           "mesh.remesh=off",  # a coarse sphere: kept, so its vertices lie on the radius
                           f"hydra.run.dir={out}"], cwd=ROOT, capture_output=True, text=True, timeout=180)
    assert proc.returncode == 0, proc.stderr
    record = json.loads((out / "handles.json").read_text())
    assert len(record["handles"]) == 4 and (out / "panel.png").exists() and (out / ".hydra").is_dir()
    assert np.allclose(np.linalg.norm(record["handle_positions"], axis=1), 0.04, rtol=1e-3)


def test_run_cli_keeps_tracebacks_of_real_bugs_and_restores_the_environment(monkeypatch):
    from grt.cli._common import run_cli

    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)

    def buggy():
        assert os.environ["HYDRA_FULL_ERROR"] == "1"  # Hydra re-raises, so run_cli can tell errors apart
        raise RuntimeError("a bug")

    with pytest.raises(RuntimeError, match="a bug"):
        run_cli(buggy)
    assert "HYDRA_FULL_ERROR" not in os.environ
