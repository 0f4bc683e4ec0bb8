"""``python -m grt.profile``: a robustness profile of a red-team run (random and adversarial shapes, two margins,
profile.json, profile.png, the run's report.html) and of an object alone, with the toy evaluator of
``_toy_run`` (no simulator), whose policy fails once a vertex moved farther than a seeded bar (3-9 mm for
``bar_mm=6``); and every refusal the command makes before simulating: one line, exit code 2, nothing written.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from grt.profile.measure import margins
from grt.profile.shapes import default_sizes, scale_to_size
from tests.runner._toy_run import TOY

ROOT = Path(__file__).resolve().parents[2]
TOY_EVALUATOR = ["evaluator._target_=tests.runner._toy_run.ToyEvaluator", "+evaluator.bar_mm=6"]
RUN = ["budget=smoke", "selector.k=3", "optimizer=gaussian", "budget.sigma=0.06", "budget.population=6",
       "budget.trials=4", "object=can", "budget.confirm_trials=16", *TOY]


def grt(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "WANDB_MODE": "disabled"})


@pytest.fixture(scope="module")
def bar_run(tmp_path_factory) -> Path:
    """A finished toy red-team run whose CrashShapes move vertices well past the bar."""
    run_dir = tmp_path_factory.mktemp("profile") / "run"
    res = grt("grt.run", *RUN, "+evaluator.bar_mm=6", f"hydra.run.dir={run_dir}")
    assert res.returncode == 0, res.stderr[-2000:]
    return run_dir


def test_a_direction_is_scaled_to_the_size_asked_and_the_default_ladder_halves():
    from grt.geometry.deform import ShapeDeformer
    from grt.objects import get_object
    from grt.profile.shapes import largest_mm

    mesh = get_object("can")
    deformer = ShapeDeformer(mesh, [0, 50, 100], list(range(200, 260)), method="smooth")
    theta = scale_to_size(deformer, np.random.default_rng(0).standard_normal((3, 3)), 2.5)
    assert largest_mm(deformer, theta) == pytest.approx(2.5, rel=0.01)
    assert default_sizes(172.5, 15.0) == [0.47, 0.94, 1.9, 3.8, 7.5, 15.0]


def test_the_margins_follow_the_curves_and_their_bounds():
    random = [{"size_mm": s, "score": v, "ci95": [v - 0.1, min(1, v + 0.1)]}
              for s, v in ((1, 1.0), (2, 0.95), (4, 0.85), (8, 0.2))]
    adversarial = [{"smallest_confirmed_mm": 4}, {"smallest_confirmed_mm": None}]
    m = margins(random, adversarial, threshold=0.9, sizes=[1, 2, 4, 8])
    assert m["random_mm"] == 2 and m["random_interval_mm"] == [1, 4] and not m["random_beyond"]
    assert m["adversarial_mm"] == 4 and m["adversarial_interval_mm"] == [2, 4]


def test_a_runs_profile_measures_both_curves_and_its_report_shows_it(bar_run):
    res = grt("grt.profile", f"run={bar_run}", *TOY_EVALUATOR, "profile.trials=8", "profile.shapes=2")
    assert res.returncode == 0, res.stderr[-2000:]
    folder = next((bar_run / "profile").iterdir())
    p = json.loads((folder / "profile.json").read_text())
    assert (folder / "profile.png").stat().st_size > 10_000 and (folder / "profile.jsonl").is_file()
    assert p["object"] == "can" and p["trials"] == 8 and len(p["sizes_mm"]) == 6
    assert not set(p["seeds"]) & set(json.loads((bar_run / "summary.json").read_text())["confirm"]["seeds"])
    assert [r["size_mm"] for r in p["random"]] == p["sizes_mm"] and all(len(r["shapes"]) == 2 for r in p["random"])
    m = p["margins"]
    assert m["random_mm"] is not None and 1 < m["random_mm"] < 9  # the bar is 3-9 mm
    assert m["adversarial_mm"] is not None and 2.9 < m["adversarial_mm"] < 12  # confirmed above the bar's low end
    assert m["adversarial_interval_mm"][0] < m["adversarial_mm"]
    sizes = [v["size_mm"] for d in p["adversarial"] for v in d["levels"]]
    assert sizes and all(v["ci95"][0] <= v["score"] <= v["ci95"][1] for d in p["adversarial"] for v in d["levels"])
    assert "adversarial margin" in res.stdout and "random margin" in res.stdout
    html = (bar_run / "report.html").read_text()
    assert "Robustness profile" in html and "Each confirmed CrashShape, shrunk" in html


def test_an_object_alone_gets_random_deformations_only(tmp_path):
    out = tmp_path / "alone"
    res = grt("grt.profile", "object=can", "selector.k=3", *TOY, *TOY_EVALUATOR, "profile.sizes=[1,4,16]",
              "profile.trials=8", "profile.shapes=2", f"hydra.run.dir={out}")
    assert res.returncode == 0, res.stderr[-2000:]
    p = json.loads((out / "profile.json").read_text())
    assert p["run"] is None and p["adversarial"] == [] and p["sizes_mm"] == [1.0, 4.0, 16.0]
    assert p["random"][0]["score"] == 1.0 and p["random"][-1]["score"] < 0.5  # 1 mm is below the bar, 16 above
    assert p["margins"]["adversarial_mm"] is None and "not measured" in res.stdout


@pytest.mark.parametrize(("args", "words"), [
    (["profile.sizes=[]"], "profile.sizes=[] is empty"),
    (["profile.sizes=[-1,2]"], "-1 is not a size"),
    (["profile.sizes=[1,300]"], "300 mm is beyond what the deformer keeps plausible"),
    (["object=bottle"], "object=bottle is another object"),
    (["task=insertion"], "task=insertion is another task"),
    (["profile.shapes=0"], "profile.shapes=0 is out of range"),
])
def test_bad_input_is_one_line_exit_2_and_nothing_written(bar_run, tmp_path, args, words):
    run_dir = tmp_path / "run"
    shutil.copytree(bar_run, run_dir, ignore=shutil.ignore_patterns("profile"))
    before = sorted(p.relative_to(run_dir) for p in run_dir.rglob("*"))
    res = grt("grt.profile", f"run={run_dir}", *TOY_EVALUATOR, *args)
    assert res.returncode == 2, res.stderr[-2000:]
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], res.stderr
    assert "Traceback" not in res.stderr
    assert sorted(p.relative_to(run_dir) for p in run_dir.rglob("*")) == before


def test_a_run_without_a_crashshape_is_refused(tmp_path):
    run_dir = tmp_path / "none"
    made = grt("grt.run", *RUN, "+evaluator.bar_mm=1000", f"hydra.run.dir={run_dir}")  # nothing ever fails
    assert made.returncode == 0, made.stderr[-2000:]
    before = sorted(p.relative_to(run_dir) for p in run_dir.rglob("*"))
    res = grt("grt.profile", f"run={run_dir}", *TOY_EVALUATOR)
    assert res.returncode == 2 and "found no CrashShape" in res.stderr and "no adversarial direction" in res.stderr
    assert sorted(p.relative_to(run_dir) for p in run_dir.rglob("*")) == before


def test_the_report_lists_the_margins_and_draws_them(bar_run, tmp_path):
    """After the profile of the test above: grt.report's margins table and --margins-plot read the run folder."""
    if not list((bar_run / "profile").glob("*/profile.json")):
        pytest.skip("needs the profile of test_a_runs_profile_measures_both_curves_and_its_report_shows_it")
    res = grt("grt.report", str(bar_run), "--markdown")
    assert res.returncode == 0, res.stderr[-2000:]
    row = next(ln for ln in res.stdout.splitlines() if ln.startswith("| grasp | can |") and "α" in ln)
    assert "mm" not in row and row.count("|") == 8  # S0, both margins, the smallest shape
    (tmp_path / "small.json").write_text('{"can": 2.3}')
    out = tmp_path / "margins.png"
    res = grt("grt.report", str(bar_run), "--margins-plot", str(out), "--small", str(tmp_path / "small.json"))
    assert res.returncode == 0 and out.stat().st_size > 5_000, res.stderr[-2000:]
    again = grt("grt.report", str(bar_run), "--margins-plot", str(out))
    assert again.returncode == 2 and "--overwrite" in again.stderr  # never replaced unasked


def test_a_profile_stopped_by_ctrl_c_resumes_where_it_stopped(bar_run, tmp_path):
    args = [f"run={bar_run}", *TOY_EVALUATOR, "profile.trials=8", "profile.shapes=2", "profile.sizes=[1,4,16]"]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert grt("grt.profile", *args, f"hydra.run.dir={whole}").returncode == 0
    stopped = subprocess.run([sys.executable, "-m", "grt.profile", *args, f"hydra.run.dir={cut}"], cwd=ROOT,
                             capture_output=True, text=True, timeout=600,
                             env={**os.environ, "GRT_TEST_INTERRUPT_AT": "4"})  # the 4th shape scored
    assert stopped.returncode == 130 and "interrupted" in stopped.stderr, stopped.stderr[-2000:]
    done = (cut / "profile.jsonl").read_text().splitlines()
    assert len(done) == 3 and not (cut / "profile.json").exists()
    again = grt("grt.profile", f"resume={cut}")
    assert again.returncode == 0, again.stderr[-2000:]
    assert (cut / "profile.jsonl").read_text().splitlines()[:3] == done  # kept, not simulated again
    first, second = (json.loads((d / "profile.json").read_text()) for d in (whole, cut))
    for key in ("s0", "random", "adversarial", "margins", "seeds", "trials_used"):
        assert first[key] == second[key], key
    refused = grt("grt.profile", f"resume={cut}", "profile.trials=16")
    assert refused.returncode == 2 and "profile.trials" in refused.stderr
