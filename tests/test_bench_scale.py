"""``python -m grt.bench scale``: pool vs Ray on the real insertion simulator, through the CLI, tiny settings.

Speed is the benchmark's business (docs/benchmarks.md); this checks that one run measures both backends,
gets the same outcomes from both, and ends with the JSON line the docs quote.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_scale_bench_measures_pool_and_ray_and_ends_with_json():
    proc = subprocess.run([sys.executable, "-m", "grt.bench", "scale", "--trials", "4", "--repeats", "1",
                           "--workers", "1", "--calls", "20",
                           "--population", "3", "--population-trials", "2"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "PROJECTION (computed, not measured)" in proc.stdout
    figures = json.loads(proc.stdout.strip().splitlines()[-1])
    for key in ("pool_trials_per_s", "ray_trials_per_s", "ray_over_pool", "pool_startup_s", "ray_startup_s",
                "ray_connect_s", "ray_noop_call_ms_median", "ray_driver_cpu_ms_per_trial", "ray_idle_s_per_call"):
        assert figures[key] > 0, key
    assert figures["same_outcomes"] is True
    assert figures["ray_backend"]["trials_per_node"] and figures["ray_backend"]["actors"] == 1
    projection = figures["projection"]
    assert set(projection["tasks"]) == {"grasp antipodal", "grasp contact_graspnet", "insertion insertion_state",
                                        "drawer drawer_state"}
    rows = projection["tasks"]["insertion insertion_state"]["rows"]
    assert [r["nodes"] for r in rows] == [1, 2, 4, 8, 16, 32] and rows[0]["workers"] == 16
    assert all(r["population_s"][0] <= r["population_s"][1] for r in rows)
    # a population in one call keeps more workers busy, so the projection is never slower per node count
    assert all(r["population_s"][1] <= r["per_candidate_s"][1] for r in rows)
    population = figures["population"]
    assert population["candidates"] == 3 and population["trials_per_candidate"] == 2
    for backend in ("pool", "ray"):
        assert population[backend]["trials_per_s_one_call"] > 0 and population[backend]["same_outcomes"] is True


def test_scale_bench_refuses_bad_numbers_in_one_line():
    proc = subprocess.run([sys.executable, "-m", "grt.bench", "scale", "--workers", "0"], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "--workers must be >= 1" in proc.stderr and "Traceback" not in proc.stderr
