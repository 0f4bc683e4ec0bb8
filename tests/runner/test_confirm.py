"""Confirmation of CrashShapes on fresh episodes (``budget.confirm_trials``): the statistics, and whole
``python -m grt.run`` processes with the toy evaluator of ``_toy_run`` (no simulator): a geometry-blind
coin-flip policy whose search "drops" are noise, a policy that really fails on moved shapes, and a
finished run confirmed afterwards by ``resume=DIR budget.confirm_trials=N``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from grt.confirm import confirm_seeds, holm, paired_drop_p
from grt.redteam import episode_seeds
from tests.runner._toy_run import TOY

ROOT = Path(__file__).resolve().parents[2]
SEARCH = ["budget=smoke", "selector.k=3", "optimizer=gaussian", "budget.sigma=0.06", "budget.population=6",
          "budget.trials=4", "object=can", *TOY]


def grt(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "WANDB_MODE": "disabled"})


def summary(run_dir: Path) -> dict:
    return json.loads((run_dir / "summary.json").read_text())


def test_fresh_seeds_are_repeatable_apart_from_the_search_and_nested():
    search = episode_seeds(42, 16)
    seeds = confirm_seeds(42, 32, search)
    assert seeds == confirm_seeds(42, 32, search) and len(set(seeds)) == 32
    assert not set(seeds) & set(search)
    assert confirm_seeds(42, 8, search) == seeds[:8]
    assert confirm_seeds(43, 8, search) != seeds[:8]


def test_the_paired_test_sees_a_real_drop_and_not_a_tie():
    ones, zeros = np.ones(10), np.zeros(10)
    assert paired_drop_p(zeros, ones) == pytest.approx(2.0**-10)  # exact: one sign pattern of 1024 as low
    assert paired_drop_p(ones, ones) == 1.0
    assert paired_drop_p(ones, zeros) == 1.0  # better than nominal: no drop
    rng = np.random.default_rng(0)
    nominal = rng.random(40) < 0.6
    assert paired_drop_p(nominal.astype(float), nominal.astype(float)) == 1.0
    worse = np.where(rng.random(40) < 0.7, 0.0, nominal)  # a shape that breaks most episodes
    assert paired_drop_p(worse, nominal) < 0.01
    noisy = (rng.random(40) < 0.6).astype(float)  # the same rate, re-drawn
    assert paired_drop_p(noisy, nominal.astype(float)) > 0.05
    # sim_error episodes (NaN) are left out, not counted as failures
    assert paired_drop_p(np.array([np.nan, 1.0, 1.0]), np.ones(3)) == 1.0


def test_holm_adjusts_in_order_and_never_below_the_raw_p():
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    p = [0.2, 0.001, 0.5, 0.01]
    assert all(a >= r for a, r in zip(holm(p), p, strict=True))


def test_a_geometry_blind_policys_search_drop_is_not_confirmed(tmp_path):
    """Every trial a coin flip: the search's lowest 4-trial score looks like a drop; fresh episodes say not."""
    run_dir = tmp_path / "coin"
    res = grt("grt.run", *SEARCH, "+evaluator.coin=0.6", "budget.confirm_trials=24", f"hydra.run.dir={run_dir}")
    assert res.returncode == 0, res.stderr[-2000:]
    s = summary(run_dir)
    assert s["final_drop"] >= 0.5  # the winner's curse: the minimum of 12 noisy scores
    floor = s["noise_floor"]  # ... which the noise floor expects of a search where nothing matters
    assert floor["candidates"] == 12 - s["invalid_candidates"] and floor["trials"] == 4
    assert s["final_drop"] <= floor["q95"]
    assert floor["p_value"] > 0.05 and "noise floor of Final Drop" in res.stdout
    conf = s["confirm"]
    assert conf["trials"] == 24 and len(conf["seeds"]) == 24
    assert conf["confirmed"] == 0 and not any(c["confirmed"] for c in conf["shapes"])
    assert s["confirmed_final_drop"] == conf["shapes"][0]["drop"] < s["final_drop"]
    assert [c["rank"] for c in conf["shapes"]] == [c["rank"] for c in s["crashshapes"]]
    lines = (run_dir / "confirm-24.jsonl").read_text().splitlines()
    assert len(lines) == 1 + len(s["crashshapes"])  # the nominal object and each CrashShape, once
    assert all(len(json.loads(ln)["trials"]) == 24 for ln in lines)
    assert "not confirmed" in res.stdout and "confirmed on 24 fresh episodes" in res.stdout


def test_a_shape_that_breaks_the_policy_is_confirmed_and_reported(tmp_path):
    run_dir = tmp_path / "bar"
    res = grt("grt.run", *SEARCH, "+evaluator.bar_mm=6", "budget.confirm_trials=24", f"hydra.run.dir={run_dir}")
    assert res.returncode == 0, res.stderr[-2000:]
    conf = summary(run_dir)["confirm"]
    assert conf["s0"] == 1.0 and conf["confirmed"] == len(conf["shapes"]) >= 1
    assert conf["confirmed_final_drop"] > 0.5 and all(c["p_holm"] < 0.05 for c in conf["shapes"])
    assert conf["confirmed_drop_ci95"][0] > 0.5 and conf["confirmed_p"] == conf["shapes"][0]["p_holm"]
    report = grt("grt.report", str(run_dir))
    assert report.returncode == 0 and "Confirmed drop (%)" in report.stdout
    assert f"({conf['confirmed']}/{len(conf['shapes'])})" in report.stdout
    head = report.stdout.splitlines()[0]
    assert head.index("Confirmed drop") < head.index("Final Drop") < head.index("noise floor")


def test_a_finished_run_is_confirmed_by_its_resume_without_searching_again(tmp_path):
    run_dir = tmp_path / "later"
    first = grt("grt.run", *SEARCH, "+evaluator.coin=0.6", "budget.confirm_trials=0", f"hydra.run.dir={run_dir}")
    assert first.returncode == 0, first.stderr[-2000:]
    assert "confirm" not in summary(run_dir)
    journal = (run_dir / "journal.jsonl").read_bytes()
    again = grt("grt.run", f"resume={run_dir}", "budget.confirm_trials=16")
    assert again.returncode == 0, again.stderr[-2000:]
    s = summary(run_dir)
    assert s["evaluated_this_session"] == 0 and (run_dir / "journal.jsonl").read_bytes() == journal
    assert s["confirm"]["trials"] == 16
    confirmations = (run_dir / "confirm-16.jsonl").read_bytes()
    third = grt("grt.run", f"resume={run_dir}", "budget.confirm_trials=16")  # replayed, not scored again
    assert third.returncode == 0 and (run_dir / "confirm-16.jsonl").read_bytes() == confirmations
    assert summary(run_dir)["confirm"] == s["confirm"]
