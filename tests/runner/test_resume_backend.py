"""Ctrl-C stops an ``evaluator=ray`` run cleanly (journal intact, Ray stopped), and the run resumes on the
local pool: a resume may change where trials run, never what they give. Real simulator, real Ray."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from grt.runfolder.record import ResumeError
from grt.runfolder.resume import resume_overrides

ROOT = Path(__file__).resolve().parents[2]
RUN = ["task=insertion", "policy=insertion_state", "budget=smoke", "budget.iterations=3"]
TIMING = ("wall_s", "sha256")  # a record's hash covers its wall time


def grt_run(*args: str) -> subprocess.Popen:
    # SIGINT at its default, as a terminal gives it: a process started with SIGINT ignored (an earlier test of
    # the session may leave it so in pytest, as `cmd &` does in a script) never sees Ctrl-C, by Unix's rules
    return subprocess.Popen([sys.executable, "-m", "grt.run", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env={**os.environ, "WANDB_MODE": "disabled"},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def journal(run_dir: Path) -> list[dict]:
    return [{k: v for k, v in json.loads(line).items() if k not in TIMING}
            for line in (run_dir / "journal.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_ctrl_c_stops_a_ray_run_and_the_pool_finishes_it_with_the_same_journal(tmp_path):
    reference = tmp_path / "pool"
    done = grt_run(*RUN, f"hydra.run.dir={reference}")  # the uninterrupted run, beside the one interrupted
    run_dir = tmp_path / "ray"
    proc = grt_run(*RUN, "evaluator=ray", f"hydra.run.dir={run_dir}")
    lines = run_dir / "journal.jsonl"
    end = time.monotonic() + 240
    while not (lines.exists() and len(lines.read_text().splitlines()) >= 3) and proc.poll() is None:
        assert time.monotonic() < end, "the Ray run wrote no journal"
        time.sleep(0.1)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    out = proc.communicate(timeout=120)[0]
    assert proc.returncode == 130, out
    assert f"continue this run with: python -m grt.run resume={run_dir}" in out
    assert "Traceback" not in out
    out = done.communicate(timeout=300)[0]
    assert done.returncode == 0, out
    kept = journal(run_dir)
    assert 3 <= len(kept) < len(journal(reference))
    assert kept == journal(reference)[:len(kept)]  # every line written is whole and as the pool's

    resumed = grt_run(f"resume={run_dir}", "evaluator=sim")
    out = resumed.communicate(timeout=300)[0]
    assert resumed.returncode == 0, out
    assert journal(run_dir) == journal(reference)
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["evaluator"]["backend"] == "pool"


def test_a_resume_may_change_the_backend_but_not_the_collision_geometry(tmp_path):
    run_dir = ROOT / "tests" / "data" / "run_format1_toy"
    given = resume_overrides([f"resume={run_dir}", "evaluator=ray", "evaluator.address=auto",
                              "evaluator.trial_timeout=30"])
    assert "evaluator=ray" in given and "evaluator.address=auto" in given
    with pytest.raises(ResumeError, match="evaluator.collision"):
        resume_overrides([f"resume={run_dir}", "evaluator.collision=coacd"])
