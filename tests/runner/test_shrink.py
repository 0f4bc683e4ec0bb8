"""Shrinking confirmed CrashShapes (``budget.shrink``): the sequential paired test's error and its early stops,
and whole ``python -m grt.run`` processes with the toy evaluator of ``_toy_run`` (no simulator) whose policy
fails once a vertex moved farther than a seeded bar: the smallest scale found, its files and figures, a
shrink interrupted by Ctrl-C resumed where it stopped, and a finished run shrunk by its resume.
"""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from grt.sequential import CANNOT_CONFIRM, CONFIRMED, PairedTest
from grt.shrink import ShrinkSettings
from tests.runner._toy_run import TOY

ROOT = Path(__file__).resolve().parents[2]
SEARCH = ["budget=smoke", "selector.k=3", "optimizer=gaussian", "budget.sigma=0.06", "budget.population=6",
          "budget.trials=4", "object=can", "+evaluator.bar_mm=6", "budget.confirm_trials=24", *TOY]


def grt(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.run", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "WANDB_MODE": "disabled", **(env or {})})


def summary(run_dir: Path) -> dict:
    return json.loads((run_dir / "summary.json").read_text())


def _decide(test: PairedTest, shape: np.ndarray) -> tuple[bool, int]:
    """Run ``shape``'s scores through the rounds as the evaluators do: (confirmed, trials run)."""
    for n in test.at:
        verdict = test.stop(list(shape[:n]))
        if verdict is not None:
            return verdict["stopped"] == CONFIRMED, n
    return test.verdict(list(shape))["confirmed"], test.trials


def test_the_sequential_test_never_confirms_more_often_than_alpha_under_the_null():
    """Exact over every sign pattern of the discordant episodes (the null: each -1 or +1 with probability 1/2,
    whichever episodes are discordant): -1 is the nominal passing and the shape failing, +1 the reverse."""
    for discordant in ([0, 2, 3, 5, 6, 7, 9, 10, 11], list(range(12)), [1, 4, 8, 10]):
        rejected = 0
        for signs in itertools.product((-1, 1), repeat=len(discordant)):
            nominal, shape = np.ones(12), np.ones(12)
            for j, sign in zip(discordant, signs, strict=True):
                nominal[j], shape[j] = (1.0, 0.0) if sign < 0 else (0.0, 1.0)
            rejected += _decide(PairedTest(tuple(nominal), alpha=0.05, rounds=4), shape)[0]
        assert rejected / 2 ** len(discordant) <= 0.05


def test_a_clear_drop_stops_early_and_a_shape_like_the_nominal_stops_unconfirmed():
    test = PairedTest(tuple([1.0] * 32), alpha=0.05 / 3, rounds=8)
    assert _decide(test, np.zeros(32)) == (True, 8)  # eight -1s: p = 2^-8 within the first look's share
    confirmed, n = _decide(test, np.ones(32))
    assert not confirmed and n == 16  # no drop seen by half the episodes
    assert test.stop([1.0] * 16)["stopped"] == CANNOT_CONFIRM
    rng = np.random.default_rng(0)
    half = (rng.random(32) < 0.5).astype(float)
    assert _decide(test, half)[0]  # a 50% drop from a nominal that never fails
    # with a sim_error the scores no longer pair with the seeds: the shape goes on
    assert test.stop([0.0] * 7, errors=1) is None


def test_a_continuous_score_runs_every_episode_and_uses_the_fixed_test():
    test = PairedTest(tuple([0.3] * 12), alpha=0.05, rounds=4, binary=False)
    assert test.at == () and test.stop([0.0] * 6) is None
    assert test.verdict([0.1] * 12)["confirmed"] and not test.verdict([0.3] * 12)["confirmed"]


def test_the_ladder_goes_down_by_the_ratio_to_the_smallest_scale():
    assert ShrinkSettings(0.5, 0.1).ladder() == [0.5, 0.25, 0.125]
    assert ShrinkSettings(0.7, 0.05).ladder()[-1] == pytest.approx(0.7 ** 8, abs=1e-6)
    with pytest.raises(ValueError):
        ShrinkSettings(1.2, 0.1).ladder()


def test_a_run_shrinks_each_confirmed_crashshape_and_writes_its_smallest_stl(tmp_path):
    run_dir = tmp_path / "bar"
    res = grt(*SEARCH, f"hydra.run.dir={run_dir}")
    assert res.returncode == 0, res.stderr[-2000:]
    s = summary(run_dir)
    block, confirmed = s["shrink"], [c for c in s["confirm"]["shapes"] if c["confirmed"]]
    assert len(block["shapes"]) == len(confirmed) >= 1 and block["level_alpha"] == pytest.approx(0.05 / len(confirmed))
    for shape, entry in zip(block["shapes"], s["crashshapes"], strict=False):
        assert 0 < shape["alpha"] < 1  # the bar policy breaks well before the CrashShape's full size
        assert shape["largest_mm"] < shape["full"]["largest_mm"] and shape["largest_mm"] > 2.9  # bar >= 3 mm
        assert shape["mean_mm"] <= shape["largest_mm"] and shape["largest_frac"] > 0
        assert shape["validity"]["valid"] and "delta_complexity" in shape
        alphas = [p["alpha"] for p in shape["curve"]]
        assert alphas[0] == 0.0 and alphas[-1] == 1.0 and alphas == sorted(alphas)
        assert all(p["ci95"][0] <= p["score"] <= p["ci95"][1] for p in shape["curve"])
        smallest = entry["smallest"]
        assert smallest["alpha"] == shape["alpha"] and smallest["file"].endswith("_smallest.stl")
        assert (run_dir / smallest["file"]).is_file()
    assert block["trials_used"] == sum(len(json.loads(ln)["trials"])
                                       for ln in (run_dir / "shrink-24.jsonl").read_text().splitlines())


def test_a_shrink_interrupted_by_ctrl_c_resumes_where_it_stopped(tmp_path):
    whole = tmp_path / "whole"
    assert grt(*SEARCH, f"hydra.run.dir={whole}").returncode == 0
    run_dir = tmp_path / "cut"
    # 13 search meshes, 3 confirmation meshes, then the shrink's: the 19th mesh is its third level
    cut = grt(*SEARCH, f"hydra.run.dir={run_dir}", env={"GRT_TEST_INTERRUPT_AT": "19"})
    assert cut.returncode != 0 and "resume=" in cut.stderr + cut.stdout
    done = (run_dir / "shrink-24.jsonl").read_text().splitlines()
    assert 1 <= len(done) < len((whole / "shrink-24.jsonl").read_text().splitlines())
    again = grt(f"resume={run_dir}")
    assert again.returncode == 0, again.stderr[-2000:]
    lines = (run_dir / "shrink-24.jsonl").read_text().splitlines()
    assert lines[:len(done)] == done  # kept, not simulated again
    drop = lambda block: {k: v for k, v in block.items() if k != "wall_s"}  # noqa: E731 - this session's time
    assert drop(summary(run_dir)["shrink"]) == drop(summary(whole)["shrink"])


def test_a_finished_run_without_a_shrink_is_shrunk_by_its_resume(tmp_path):
    run_dir = tmp_path / "later"
    first = grt(*SEARCH, "budget.shrink=false", f"hydra.run.dir={run_dir}")
    assert first.returncode == 0, first.stderr[-2000:]
    assert "shrink" not in summary(run_dir) and not list(run_dir.glob("crashshapes/*_smallest.stl"))
    journal, confirmation = (run_dir / "journal.jsonl").read_bytes(), (run_dir / "confirm-24.jsonl").read_bytes()
    again = grt(f"resume={run_dir}", "budget.shrink=true")
    assert again.returncode == 0, again.stderr[-2000:]
    assert (run_dir / "journal.jsonl").read_bytes() == journal  # neither searched nor confirmed again
    assert (run_dir / "confirm-24.jsonl").read_bytes() == confirmation
    assert summary(run_dir)["shrink"]["shapes"] and list(run_dir.glob("crashshapes/*_smallest.stl"))
    third = grt(f"resume={run_dir}", "budget.shrink=true")
    assert third.returncode == 0 and "nothing to do" in third.stdout


def test_a_size_penalty_steers_the_search_to_smaller_shapes_and_journals_plain_scores(tmp_path):
    """``budget.size_penalty``: the search is told score + penalty x S0 x SS / tau; its elites, and so the later
    iterations' candidates, are smaller than without it; the journal keeps the simulated scores."""
    common = ["budget=smoke", "selector.k=3", "budget.sigma=0.06", "budget.population=6", "budget.iterations=3",
              "budget.trials=4", "object=can", "+evaluator.bar_mm=6", "budget.tau=0.01", *TOY]
    sizes = {}
    for penalty in (0, 4):
        run_dir = tmp_path / f"p{penalty}"
        res = grt(*common, f"budget.size_penalty={penalty}", f"hydra.run.dir={run_dir}")
        assert res.returncode == 0, res.stderr[-2000:]
        records = [json.loads(ln) for ln in (run_dir / "journal.jsonl").read_text().splitlines()]
        assert all(r["score"] is None or 0 <= r["score"] <= 1 for r in records)  # plain success rates
        sizes[penalty] = np.mean([r["smoothness_m"] for r in records if r["iteration"] == 3])
        assert summary(run_dir)["size_penalty"] == penalty
    assert sizes[4] < sizes[0]
