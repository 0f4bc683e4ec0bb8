"""What a run calls a CrashShape (issue 33 §3): only a candidate that scores below S0 by the task's margin.
A run in which nothing failed says "no CrashShape found" on its final screen, in summary.json and in the
report, and keeps its best candidates in best/, named as such."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.runner._toy_run import TOY

ROOT = Path(__file__).resolve().parents[2]
SEARCH = ["budget=smoke", "selector.k=3", "optimizer=gaussian", "budget.sigma=0.06", "budget.population=4",
          "budget.trials=4", "object=can", *TOY]


def grt(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "WANDB_MODE": "disabled"})


def test_a_zero_drop_run_names_no_crashshape_and_keeps_its_best_as_best(tmp_path):
    run_dir = tmp_path / "nodrop"
    res = grt("grt.run", *SEARCH, "+evaluator.coin=1.0", f"hydra.run.dir={run_dir}")  # every trial succeeds
    assert res.returncode == 0, res.stderr[-2000:]
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["final_drop"] == 0.0 and s["crashshape_found"] is False and s["crashshapes"] == []
    assert s["crash_margin"] == 0.1 and "no CrashShape found" in s["note"]
    best = s["best_candidates"]
    assert best and all(e["file"].startswith("best/") and (run_dir / e["file"]).is_file() for e in best)
    assert not (run_dir / "crashshapes").exists() or not any((run_dir / "crashshapes").glob("rank*"))
    screen = " ".join(res.stdout.split())
    assert "no CrashShape found" in screen and "CrashShapes:" not in screen
    report = grt("grt.report", str(run_dir))
    assert report.returncode == 0 and "(no CrashShape)" in report.stdout


@pytest.mark.slow
def test_a_run_with_a_real_drop_keeps_its_crashshapes_and_only_those(tmp_path):
    run_dir = tmp_path / "drop"
    res = grt("grt.run", *SEARCH, "+evaluator.bar_mm=6", f"hydra.run.dir={run_dir}")
    assert res.returncode == 0, res.stderr[-2000:]
    s = json.loads((run_dir / "summary.json").read_text())
    assert s["crashshape_found"] is True and "best_candidates" not in s
    assert all(e["score"] <= 0.9 * s["s0"] for e in s["crashshapes"]) and s["crashshapes"]
    assert all(e["file"].startswith("crashshapes/") for e in s["crashshapes"])


def test_a_bad_margin_is_refused_in_one_line(tmp_path):
    res = grt("grt.run", *SEARCH, "task.crash_margin=1.5", f"hydra.run.dir={tmp_path / 'bad'}")
    out = res.stdout + res.stderr
    assert res.returncode == 2 and "task.crash_margin=1.5: give the least drop" in out and "Traceback" not in out
