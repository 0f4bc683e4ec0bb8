"""The commands read in a log (stdout and stderr piped, issue 30 item 17): no carriage returns, no line
wrapped or longer than 200 characters (bar the documented JSON line), a start-up line before the first
trial, the saved path, one rate; ``--help`` without internal groups."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _piped(*args: str) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return proc


def _log_lines(proc: subprocess.CompletedProcess, machine_lines: int = 0) -> list[str]:
    text = proc.stdout + proc.stderr
    assert "\r" not in text and "Traceback" not in text
    lines = proc.stdout.splitlines()
    lines = lines[:len(lines) - machine_lines] + proc.stderr.splitlines()
    assert max(len(line) for line in lines) <= 200, max(lines, key=len)
    return lines


@pytest.mark.slow
def test_evaluate_in_a_log(grasp_evaluation):
    out, proc = grasp_evaluation  # python -m grt.evaluate ... budget.trials=2 budget.workers=1, piped (conftest.py)
    _log_lines(proc, machine_lines=1)  # the last line is the JSON object (the command's output for scripts)
    stdout = proc.stdout.splitlines()
    start = next(i for i, line in enumerate(stdout) if line.startswith("starting 1 simulator worker"))
    assert stdout[start + 1].startswith("1 simulator worker ready in")
    summary = json.loads(stdout[-1])
    assert summary["saved"] == str(out / "evaluation.json") and (out / "evaluation.json").is_file()
    assert f"saved         {out / 'evaluation.json'}" in proc.stdout
    progress = [line for line in proc.stderr.splitlines() if line.startswith("trials: ")]
    assert progress and progress[-1].startswith("trials: 2/2 (100%)"), proc.stderr
    shown = float(re.search(r", ([0-9.]+) trial/s", progress[-1]).group(1))
    assert abs(shown - summary["trials_per_s"]) <= 0.05 * summary["trials_per_s"], (progress[-1], summary)
    assert summary["wall_s"] >= summary["startup_s"] + summary["trials_s"]


@pytest.mark.slow
def test_run_in_a_log(grasp_smoke_run):
    out, proc = grasp_smoke_run  # python -m grt.run budget=smoke ..., piped (conftest.py)
    lines = _log_lines(proc)
    assert any(line.startswith("starting 1 simulator worker") for line in proc.stdout.splitlines())
    assert [line for line in proc.stderr.splitlines() if line.startswith("red-team: 7/7 (100%)")]
    assert "ΔComplexity" in proc.stdout and "…" not in proc.stdout  # the table's headers whole
    assert f"  curve: {out / 'curve.png'}" in lines
    assert proc.stdout.count("Smoothness-Score cap") == 1  # said once, before the search (issue 40)


@pytest.mark.parametrize("app", ["run", "evaluate"])
def test_help_lists_only_the_commands_own_choices(app):
    text = _piped(f"grt.{app}", "--help").stdout
    groups = text.split("== Configuration groups ==")[1].split("== Config ==")[0]
    names = [line.split(":")[0] for line in groups.splitlines() if re.match(r"^\w+: ", line)]
    assert "task" in names and "policy" in names and "budget" in names
    assert not {"paths", "hydra", "train", "blueteam"} & set(names) and "schema" not in groups
    assert ("optimizer" in names) == (app == "run")  # evaluate composes no optimizer
