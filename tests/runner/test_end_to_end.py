"""The whole loop on the real simulator with tiny budgets: a run, kill -9 and resume, a sweep."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from omegaconf import OmegaConf

pytestmark = [pytest.mark.sim, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[2]
# Small cameras keep CPU rendering cheap; the loop is what is under test here (with 2 trials S0 may be 0:
# no nominal floor, which test_nominal_floor.py covers).
FAST = ["budget=smoke", "task.session.num_cameras=2", "task.session.camera_width=160",
        "task.session.camera_height=120", "selector.k=4", "task.nominal_floor=null"]


def journal_keys(run_dir: Path) -> list[tuple[int, int]]:
    lines = (run_dir / "journal.jsonl").read_text().splitlines()
    return [(r["iteration"], r["candidate"]) for r in map(json.loads, lines)]


def test_smoke_run_writes_every_artifact(grasp_smoke_run):
    run_dir, _ = grasp_smoke_run  # python -m grt.run with FAST and budget.confirm_trials=2 (tests/conftest.py)
    cfg = OmegaConf.load(run_dir / ".hydra" / "config.yaml")
    summary = json.loads((run_dir / "summary.json").read_text())
    n = 1 + cfg.budget.population * cfg.budget.iterations
    assert journal_keys(run_dir) == [(0, 0)] + [(t, i) for t in (1, 2) for i in range(3)]
    assert summary["evaluations"] == n
    for name in ("summary.json", "curve.png", "shapes.png", "handles.json"):
        assert (run_dir / name).stat().st_size > 0, name
    assert 0.0 <= summary["s0"] <= 1.0
    assert summary["final_drop"] >= 0 or summary["s0"] == 0
    found = summary["crashshape_found"]  # a smoke run often finds no drop: its best candidates go to best/
    shapes = summary["crashshapes"] if found else summary["best_candidates"]
    assert len(shapes) == cfg.budget.top_k and all(s["watertight"] for s in shapes)
    assert (run_dir / shapes[0]["file"]).exists()
    assert (run_dir / ("crashshapes" if found else "best") / "handles.json").exists()
    assert list((run_dir / shapes[0]["parts"]).glob("part*.obj")), "convex parts not saved"
    assert summary["selector"] == "heuristic" and summary["optimizer"] == "topdm"
    rec = json.loads((run_dir / "journal.jsonl").read_text().splitlines()[1])
    assert {"theta", "score", "trials", "outcomes", "smoothness_m", "entropy", "mesh_hash"} <= set(rec)
    assert len(rec["trials"]) == cfg.budget.trials
    if not found:  # nothing failed: nothing to confirm (the toy runs of test_confirm.py cover a drop)
        assert "confirm" not in summary and not list(run_dir.glob("confirm-*.jsonl"))
        return
    # the CrashShapes confirmed on fresh episodes by the real simulator, journaled apart from the search
    conf = summary["confirm"]
    assert len(conf["seeds"]) == 2 and not set(conf["seeds"]) & {t["seed"] for t in rec["trials"]}
    assert [c["rank"] for c in conf["shapes"]] == [s["rank"] for s in shapes]
    assert all(0.0 <= c["score"] <= 1.0 or c["score"] != c["score"] for c in conf["shapes"])
    assert len((run_dir / "confirm-2.jsonl").read_text().splitlines()) == 1 + len(shapes)


def _cli(args, **kw):
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "WANDB_MODE": "disabled"}
    return subprocess.Popen([sys.executable, "-m", "grt.run", *args], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


def test_kill_9_then_resume_loses_nothing_and_repeats_nothing(tmp_path):
    run_dir = tmp_path / "run"
    proc = _cli([*FAST, f"hydra.run.dir={run_dir}"], start_new_session=True)
    journal = run_dir / "journal.jsonl"
    deadline = time.time() + 240
    while time.time() < deadline:
        if journal.exists() and len(journal.read_text().splitlines()) >= 3:
            break
        if proc.poll() is not None:
            pytest.fail("run ended before it could be killed:\n" + proc.stdout.read())
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    before = journal.read_text().splitlines()
    with open(journal, "a") as f:  # as if the kill hit in the middle of a write
        f.write('{"iteration": 9, "cand')
    proc = _cli([*FAST, f"resume={run_dir}"])
    out, _ = proc.communicate(timeout=400)
    assert proc.returncode == 0, out
    keys = journal_keys(run_dir)
    assert len(keys) == len(set(keys)) == 7, keys  # nothing repeated, nothing lost
    assert journal.read_text().splitlines()[: len(before)] == before
    summary = json.loads((run_dir / "summary.json").read_text())
    assert summary["evaluated_this_session"] == 7 - len(before)


# A sweep's jobs: what is under test is that each starts its simulator and finishes (or fails alone), so one
# generation of 1-trial candidates is search enough (the simulator's start costs the most).
SWEEP_JOB = ["budget.iterations=1", "budget.trials=1"]


def test_multirun_goes_on_after_a_failing_job(tmp_path):
    proc = _cli(["-m", *FAST, *SWEEP_JOB, "object=no_such_object,can", f"hydra.sweep.dir={tmp_path}"])
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 1, out  # the sweep went on, and its command says a job failed (grt/cli/sweeps.py)
    assert f"error: 1 of 2 jobs of the sweep failed: 0_antipodal_heuristic-topdm (error: {tmp_path}/0_antipodal_heuristic-topdm" in out
    errors = list(tmp_path.rglob("error.txt"))
    summaries = list(tmp_path.rglob("summary.json"))
    assert len(errors) == 1 and "no_such_object" in errors[0].read_text()
    assert len(summaries) == 1
    report = subprocess.run([sys.executable, "-m", "grt.report", str(tmp_path)], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout
    assert "Final Drop" in report and "can" in report and "1 failed job" in report


def test_multirun_with_the_joblib_launcher(tmp_path):
    # loky installs its own start method; the evaluator's spawned workers must still start
    fast = [o for o in FAST if not o.startswith("selector.")]  # `all` has no k
    proc = _cli(["-m", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", *fast, *SWEEP_JOB, "budget.workers=1",
                 "selector=heuristic,all", f"hydra.sweep.dir={tmp_path}"])
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out
    assert not list(tmp_path.rglob("error.txt")), out
    assert len(list(tmp_path.rglob("summary.json"))) == 2
