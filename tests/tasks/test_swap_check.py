"""The swap check of a ManiSkill task (grt/agreement.py, grt/swapcheck.py): its statistics, and real runs of a
box task whose copy is made unfaithful on purpose (a cube's convex part capped at 4 vertices: a tetrahedron
the expert cannot pick): refused in one line with nothing left behind, and run with the override, recorded.
A faithful box copy is checked, printed and cached in tests/policies/test_motion_planner.py's evaluation."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from grt.agreement import MIN_AGREEMENT, SwapCheckError, SwapCheckSettings, compare, error_rates, mcnemar_p
from grt.config import plain
from grt.swapcheck import check_settings, not_checked
from tests.runner.conftest import compose_run

ROOT = Path(__file__).resolve().parents[2]


def test_agreement_counts_same_outcomes_and_mcnemar_tests_the_success_rates():
    # the round actor's calibration: stock 5/16, swap 14/16, agreeing on 6 seeds
    stock = ["success"] * 5 + ["timeout"] * 11
    swap = ["success"] * 5 + ["success"] * 9 + ["timeout"] * 2
    record = compare(stock, swap, list(range(16)), SwapCheckSettings())
    assert record["agreement"] == pytest.approx(7 / 16) and not record["passed"] and not record["accepted"]
    assert record["mcnemar_p"] == pytest.approx(2 * 0.5**9)
    assert (record["stock"]["success_rate"], record["swap"]["success_rate"]) == (5 / 16, 14 / 16)
    accepted = compare(stock, swap, list(range(16)), SwapCheckSettings(accept=True))
    assert accepted["accepted"] and not accepted["passed"]
    # another failure mode is a disagreement; a simulator error on both sides is no agreement
    assert compare(["success", "not_grasped"], ["success", "not_placed"], [1, 2], SwapCheckSettings())["agreement"] == 0.5
    assert compare(["sim_error"], ["sim_error"], [1], SwapCheckSettings())["agreement"] == 0.0
    assert mcnemar_p([True, False], [True, False]) == 1.0


def test_the_default_threshold_passes_the_measured_good_copies_and_refuses_the_bad_ones():
    measured = {"box tasks": 1.0, "PlugCharger": 0.85, "LiftPegUpright": 0.9, "round actor": 0.375,
                "compound tool": 0.438}
    verdict = {name: a >= MIN_AGREEMENT for name, a in measured.items()}
    assert verdict == {"box tasks": True, "PlugCharger": True, "LiftPegUpright": True, "round actor": False,
                       "compound tool": False}
    refuse_good, pass_bad = error_rates(8)
    assert refuse_good == pytest.approx(0.105, abs=1e-3) and pass_bad == pytest.approx(0.079, abs=1e-3)
    assert max(error_rates(32)) < 0.05


@pytest.mark.parametrize(("node", "words"), [
    ({"min_agreement": 1.5}, "swap_check.min_agreement=1.5: give a number in [0, 1]"),
    ({"accept": "yes"}, "swap_check.accept='yes': give true or false"),
    ({"min_agreemnt": 0.5}, "swap_check.min_agreemnt is not a swap-check setting"),
])
def test_bad_settings_are_one_line(node, words):
    with pytest.raises(SwapCheckError, match=words.replace("[", r"\[").replace("]", r"\]")):
        SwapCheckSettings.from_config(node)


def test_grts_own_tasks_have_no_stock_env_and_an_override_for_them_is_refused():
    grasp = plain(compose_run(["task=grasp"]).task)
    assert not_checked(grasp, "mug").startswith("no stock env: task=grasp is GRT's own task")
    with pytest.raises(SwapCheckError, match="swap_check.accept=true: no stock env: task=grasp .* drop swap_check.accept"):
        check_settings(grasp, "mug", SwapCheckSettings(accept=True))
    cube = plain(compose_run(["task=pick_cube"]).task)
    assert not_checked(cube, "actor") is None and "not the stock env's own actor" in not_checked(cube, "mug")


UNFAITHFUL = ["task=pick_cube", "policy=pick_cube_expert", "budget=smoke", "budget.trials=2", "budget.workers=1",
              "evaluator.max_hull_vertices=4"]  # the cube's copy: a tetrahedron


def _run(*args: str, cache: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.run", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "GRT_CACHE_DIR": str(cache), "WANDB_MODE": "disabled"})


@pytest.mark.sim
def test_a_disagreeing_copy_is_refused_in_one_line_and_runs_knowingly_with_the_override(tmp_path):
    out = tmp_path / "run"
    refused = _run(*UNFAITHFUL, f"hydra.run.dir={out}", cache=tmp_path / "cache")
    text = refused.stdout + refused.stderr
    errors = [line for line in text.splitlines() if line.startswith("error:")]
    assert refused.returncode == 2 and "Traceback" not in text and len(errors) == 1, text[-3000:]
    assert re.search(r"the stock env succeeds on 2/2 seeds and GRT's nominal swap on [01]/2 of the same seeds; "
                     r"per-seed agreement 0\.\d+ < swap_check\.min_agreement=0\.75", errors[0]), errors[0]
    assert "swap_check.accept=true" in errors[0]
    assert not out.exists()  # nothing journaled, no folder left
    assert not (tmp_path / "cache" / "swapcheck").exists()  # a failing check is not cached

    accepted = _run(*UNFAITHFUL, "swap_check.accept=true", "task.nominal_floor=null", "budget.population=1",
                    "budget.iterations=1", f"hydra.run.dir={out}", cache=tmp_path / "cache")
    assert accepted.returncode == 0, (accepted.stdout + accepted.stderr)[-3000:]
    check = json.loads((out / "summary.json").read_text())["swap_check"]
    assert check["accepted"] and not check["passed"] and check["agreement"] < 0.75
    assert check["stock"]["success_rate"] == 1.0 > check["swap"]["success_rate"]
    assert accepted.stdout.count("FAILED, accepted with swap_check.accept=true") == 2  # before the search, at the end
    journal = [json.loads(line) for line in (out / "journal.jsonl").read_text().splitlines()]
    assert journal[0]["iteration"] == 0 and [t["mode"] for t in journal[0]["trials"]] == check["swap"]["modes"]
