"""Blue-teaming through its CLI on a real (tiny) insertion red-team run: rows, refusal, resume."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import torch
from omegaconf import OmegaConf

from tests.blueteam.conftest import ROOT, _cli

TINY = ["blueteam.iterations=2", "blueteam.num_envs=2", "blueteam.num_steps_per_env=8", "blueteam.max_steps=16",
        "blueteam.eval_trials=1", "blueteam.val_trials=1", "blueteam.val_trials_nominal=2", "blueteam.val_interval=1", "blueteam.heldout.candidates=1",
        "blueteam.heldout.nearby=1", "blueteam.confirm.candidates=2", "blueteam.confirm.trials=2",
        "blueteam.anchor.updates=2", "blueteam.anchor.envs=2", "blueteam.anchor.steps=4", "workers=1"]


@pytest.mark.sim
@pytest.mark.slow
def test_fine_tune_writes_table3_and_a_loadable_checkpoint_then_resumes(red_team_run, tmp_path):
    from grt.policies.rsl_rl import RslRlPolicy

    out_dir = tmp_path / "bt"
    res = _cli("grt.blueteam", f"run={red_team_run}", *TINY, f"hydra.run.dir={out_dir}")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    rows = json.loads((out_dir / "table3.json").read_text())
    assert rows and set(rows[0]) >= {"policy", "geometry", "orig", "blue", "nominal_before", "nominal_after",
                                     "heldout_before", "heldout_after"}
    assert all(0.0 <= rows[0][k] <= 1.0 for k in ("orig", "blue", "nominal_before", "nominal_after"))
    assert "| Orig. | Blue. |" in (out_dir / "table3.md").read_text()
    study = json.loads((out_dir / "blueteam.json").read_text())
    assert study["swap_check"]["stock"] is None  # GRT's own insertion task: recorded, not invented
    assert study["swap_check"]["note"].startswith("no stock env: task=insertion")
    rered = study["rered"]  # same budget and seed as the run
    assert set(rered["before"]) == set(rered["after"]) and rered["after"]["s0"] is not None
    assert (out_dir / "rered" / "summary.json").exists()
    policy = RslRlPolicy(str(out_dir / "policy.pt"), task="insertion")
    assert policy.config["blueteam"]["shapes"][0] == "nominal"
    assert (out_dir / "validation.png").stat().st_size > 0 and (out_dir / "validation.jsonl").read_text().count("\n") >= 2
    confirm = json.loads((out_dir / "confirm.json").read_text())  # the best 2 validations on 2 fresh episodes
    assert len(confirm["candidates"]) == 2 and sum(c["chosen"] for c in confirm["candidates"]) == 1
    assert len(confirm["episodes"]["start"]["nominal"]) == 2 and sorted((out_dir / "candidates").iterdir())
    assert all(c["nominal_episodes"] == 4 for c in confirm["candidates"])  # 2 validation + 2 fresh, pooled
    assert torch.load(out_dir / "policy.pt", weights_only=False)["iter"] + 1 == confirm["chosen"]  # exported
    guard = json.loads((out_dir / "val_nominal.json").read_text())  # early stopping's nominal baseline
    assert 0.0 <= guard["nominal"] <= 1.0 and guard["guard"] == "fisher" and len(guard["scores"]) == 2
    before = torch.load(ROOT / "grt/policies/checkpoints/insertion_state.pt", weights_only=False)["actor_state_dict"]
    after = torch.load(out_dir / "last.pt", weights_only=False)["actor_state_dict"]
    assert any(not torch.equal(before[k], after[k]) for k in before), "PPO did not change the policy"
    header, *rows = (out_dir / "metrics.csv").read_text().splitlines()  # the nominal anchor pulled every iteration
    assert header.endswith("anchor_mse") and all(float(r.split(",")[-1]) >= 0 for r in rows)
    assert "anchor: 8 nominal states of the starting policy" in res.stderr + res.stdout
    normalizer = [k for k in before if k.startswith("obs_normalizer.")]  # frozen: the inputs stay as trained
    assert normalizer and all(torch.equal(before[k], after[k]) for k in normalizer)
    # A fine-tune killed before it finished: resume=DIR continues with the study's own run= and settings (not
    # the defaults: 150 iterations, a re-red-team), from last.pt, repeating no iteration; blueteam.iterations and
    # blueteam.rered.enabled may change; the start's .hydra record stays byte for byte.
    start = {name: (out_dir / ".hydra" / name).read_bytes() for name in ("config.yaml", "overrides.yaml", "hydra.yaml")}
    (out_dir / "policy.pt").unlink()
    scores = json.loads((out_dir / "scores.json").read_text())
    scores.pop("after")
    (out_dir / "scores.json").write_text(json.dumps(scores))
    (out_dir / "val_best.pt").unlink(missing_ok=True)
    for name in ("table3.json", "table3.md", "blueteam.json"):
        (out_dir / name).unlink()
    res = _cli("grt.blueteam", "blueteam.iterations=3", "blueteam.rered.enabled=false", f"resume={out_dir}")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    iterations = [int(line.split(",")[0]) for line in (out_dir / "metrics.csv").read_text().splitlines()[1:]]
    assert iterations == [0, 1, 2]
    assert {name: (out_dir / ".hydra" / name).read_bytes() for name in start} == start
    composed = OmegaConf.load(out_dir / ".hydra" / "resume" / "config.yaml")
    assert (composed.run, composed.resume, composed.blueteam.iterations) == (str(red_team_run), str(out_dir), 3)
    assert composed.blueteam.num_envs == 2 and composed.workers == 1  # TINY's, from the study's record
    assert (out_dir / "policy.pt").is_file() and "after" in json.loads((out_dir / "scores.json").read_text())
    assert json.loads((out_dir / "blueteam.json").read_text())["run"] == str(red_team_run)
    assert (out_dir / "table3.json").is_file()
    assert "resuming" in (out_dir / "blueteam.log").read_text()


def test_an_untrainable_policy_is_refused_in_one_line(tmp_path):
    from omegaconf import OmegaConf

    from tests.runner.conftest import compose_run

    run_dir = tmp_path / "grasp_run"
    (run_dir / ".hydra").mkdir(parents=True)
    cfg = compose_run(["task=grasp", "policy=antipodal"])
    (run_dir / ".hydra" / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
    (run_dir / "handles.json").write_text('{"handles": [0], "anchors": [1, 2, 3]}')
    (run_dir / "journal.jsonl").write_text("")
    res = _cli("grt.blueteam", f"run={run_dir}", f"hydra.run.dir={tmp_path / 'bt'}")
    assert res.returncode == 2 and "cannot be fine-tuned" in res.stderr and "Traceback" not in res.stderr, res.stderr
    res = _cli("grt.blueteam", f"run={tmp_path / 'nothing'}", f"hydra.run.dir={tmp_path / 'bt2'}")
    assert res.returncode == 2 and "not a red-team run folder" in res.stderr


@pytest.mark.parametrize(("arg", "words"), [
    ("blueteam.nominal_share=1.5", "blueteam.nominal_share=1.5: give a number in [0, 1)"),  # was a traceback
    ("blueteam.iterations=0", "blueteam.iterations=0: give an integer >= 1"),  # was a whole study, untrained
    ("blueteam.top_k=0", "blueteam.top_k=0: give an integer >= 1"),  # was "no CrashShape"
])
def test_settings_out_of_range_are_one_line_before_any_simulation(arg, words, tmp_path):
    """Checked before the run is even read (a folder that is no run would be refused after them)."""
    out = tmp_path / "bt"
    res = _cli("grt.blueteam", f"run={tmp_path / 'any'}", arg, f"hydra.run.dir={out}")
    errors = [line for line in res.stderr.splitlines() if line.strip()]
    assert res.returncode == 2 and len(errors) == 1 and words in errors[0], res.stderr[-2000:]
    assert not out.exists()


@pytest.mark.parametrize("how", ["resume", "hydra.run.dir"])
def test_a_study_another_process_holds_is_refused_and_left_as_it_was(how, tmp_path):
    """A killed study is continued in its folder (``resume=DIR``, or ``hydra.run.dir=DIR``); a second one
    started while the first still runs there would mix their checkpoints and scores: it is refused (the
    first's PID named) before it writes anything there."""
    from tests.blueteam.test_blueteam_resume import write_record
    from tests.cli._locked_folder import refused_while_locked

    study = tmp_path / "bt"
    command = [f"run={tmp_path / 'redteam'}", *TINY]
    write_record(study, command)  # the record of its start: what makes it a study to resume
    (study / "metrics.csv").write_text("iteration,reward\n0,1.0\n")
    (study / "last.pt").write_bytes(b"a checkpoint")
    refused_while_locked("grt.blueteam", study, *command, f"{how}={study}")


def test_a_resume_naming_a_red_team_runs_folder_is_refused_and_left_as_it_was(tmp_path):
    """``resume=`` continues a study; a red-team run's folder is none, and its files are not the study's to
    write over: refused in one line before anything is written there."""
    from tests.cli._locked_folder import contents

    run = tmp_path / "redteam"
    (run / ".hydra").mkdir(parents=True)
    (run / "run_config.yaml").write_text("grt_format: 2\n")
    (run / "journal.jsonl").write_text("")
    before = contents(run)
    res = _cli("grt.blueteam", f"run={run}", *TINY, f"resume={run}")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    errors = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith(f"error: resume={run}: {run} already holds a red-team run"), errors
    assert "python -m grt.blueteam would overwrite" in errors[0]
    assert contents(run) == before and not (run / ".grt.lock").exists()


def test_crashshapes_are_chosen_by_rank_or_by_name():
    from grt.blueteam.core import BlueTeamError, select_crashshapes

    theta = [0.0]
    recs = [{"iteration": 0, "candidate": 0, "score": 1.0, "theta": theta},
            {"iteration": 1, "candidate": 0, "score": 0.2, "theta": theta},
            {"iteration": 1, "candidate": 1, "score": 0.9, "theta": theta},
            {"iteration": 2, "candidate": 3, "score": 0.4, "theta": theta},
            {"iteration": 2, "candidate": 4, "score": float("nan"), "theta": theta}]  # implausible, not simulated
    names = lambda chosen: [f"it{r['iteration']}_c{r['candidate']}" for r in chosen]  # noqa: E731
    assert names(select_crashshapes(recs, "top1", 3, 0.5, 1.0)) == ["it1_c0"]
    assert names(select_crashshapes(recs, "all-failing", 3, 0.5, 1.0)) == ["it1_c0", "it2_c3"]
    # the user's own choice, in the user's order, whatever it scored; file names of the run's CrashShapes work
    assert names(select_crashshapes(recs, ["it2_c3", "crashshapes/rank3_it1_c1.stl"], 3, 0.5, 1.0)) == \
        ["it2_c3", "it1_c1"]
    assert names(select_crashshapes(recs, "it2_c3", 3, 0.5, 1.0)) == ["it2_c3"]
    for bad in (["it9_c9"], ["it2_c4"], ["it0_c0"], "best"):  # unknown, not simulated, the nominal, a typo
        with pytest.raises(BlueTeamError, match="crashshapes"):
            select_crashshapes(recs, bad, 3, 0.5, 1.0)
    with pytest.raises(BlueTeamError, match="no CrashShape scoring below"):
        select_crashshapes(recs, "top1", 3, 0.1, 1.0)


def test_the_nominal_guard_refuses_a_regression_on_evidence_not_on_one_episode():
    from grt.blueteam.core import BlueTeamError, nominal_regressed

    start = [1.0] * 16
    assert not nominal_regressed(start, [1.0] * 12 + [0.0] * 4)[0]  # 12/16 vs 16/16: p = 0.051
    regressed, why = nominal_regressed(start, [1.0] * 11 + [0.0] * 5)
    assert regressed and "11/16 against 16/16" in why and "p = 0.022" in why
    assert nominal_regressed(start, [1.0] * 15 + [0.0], guard="tolerance", tolerance=0.05)[0]  # one episode
    assert not nominal_regressed(start, [1.0] * 15 + [0.0], guard="tolerance", tolerance=0.07)[0]
    # a continuous score (the drawer's opening) is judged by the tolerance whatever the guard
    assert nominal_regressed([0.38] * 8, [0.30] * 8, binary=False, tolerance=0.05)[0]
    assert not nominal_regressed([0.38] * 8, [0.35] * 8, binary=False, tolerance=0.05)[0]
    with pytest.raises(BlueTeamError, match="nominal_guard='strict' is not a guard"):
        nominal_regressed(start, start, guard="strict")


def test_the_kept_checkpoints_are_the_best_validations_the_guard_let_through():
    from grt.blueteam.core import rank_candidates

    row = lambda it, c, n, bad=False: {"iteration": it, "crashshapes": {"a": c, "b": c}, "nominal": n,  # noqa: E731
                                       "regressed": bad}
    rows = [row(0, 0.3, 1.0), row(10, 0.9, 0.7, True), row(20, 0.6, 0.9), row(30, 0.6, 1.0), row(40, 0.6, 1.0),
            row(50, 0.5, 1.0), row(50, 0.2, 1.0)]  # iteration 50 validated again after a resume: its last row
    assert [r["iteration"] for r in rank_candidates(rows, 3)] == [40, 30, 20]  # ties: nominal, then later
    assert [r["iteration"] for r in rank_candidates(rows, 9)] == [40, 30, 20, 0, 50]  # the refused one never
    assert rank_candidates(rows, 0) == []


def test_confirmation_pools_fresh_episodes_and_refuses_a_lucky_validation():
    from grt.blueteam.core import choose_confirmed

    start = [1.0] * 64  # 32 validation + 32 fresh nominal episodes of the policy before fine-tuning
    # the best validation (31/32 nominal, CrashShapes 0.81) fails 7 of 32 fresh nominal episodes: refused on
    # the pooled 56/64; the runner-up holds the nominal object and is chosen
    lucky = {"iteration": 170, "nominal": [1.0] * 31 + [0.0] + [1.0] * 25 + [0.0] * 7,
             "crashshapes": {"a": [1.0] * 13 + [0.0] * 3 + [1.0] * 24 + [0.0] * 8}}
    steady = {"iteration": 90, "nominal": [1.0] * 30 + [0.0] * 2 + [1.0] * 31 + [0.0],
              "crashshapes": {"a": [1.0] * 12 + [0.0] * 4 + [1.0] * 22 + [0.0] * 10}}
    pick, rows = choose_confirmed([lucky, steady], start)
    assert pick == 1 and [r["chosen"] for r in rows] == [False, True]
    assert not rows[0]["passed"] and "56/64 against 64/64" in rows[0]["why"] and rows[1]["passed"]
    assert rows[1]["nominal_episodes"] == 64 and rows[1]["crashshape_mean"] == pytest.approx(34 / 48)
    # no candidate holds the nominal object: the best on it is exported, marked as not passing
    pick, rows = choose_confirmed([lucky, {**steady, "nominal": [1.0] * 40 + [0.0] * 24}], start)
    assert pick == 0 and not any(r["passed"] for r in rows) and rows[0]["chosen"]
    with pytest.raises(ValueError, match="no candidate"):
        choose_confirmed([], start)


def test_validation_picture_marks_refused_checkpoints(tmp_path):
    from grt.blueteam.core import plot_validation

    rows = [{"iteration": i, "nominal": n, "crashshapes": {"it4_c7": c, "it7_c1": c / 2}, "regressed": r}
            for i, n, c, r in [(0, 1.0, 0.3, False), (10, 0.6, 0.5, True), (20, 0.9, 0.8, False)]]
    assert plot_validation(rows, tmp_path / "v.png") and (tmp_path / "v.png").stat().st_size > 1000
    assert plot_validation(rows, tmp_path / "star.png", chosen=20)  # the exported checkpoint, starred
    assert not plot_validation([], tmp_path / "none.png") and not (tmp_path / "none.png").exists()


@pytest.mark.sim
def test_in_hand_tilt_measures_the_nominal_plug_and_the_runs_candidates(red_team_run, tmp_path):
    res = subprocess.run([sys.executable, "scripts/in_hand_tilt.py", str(red_team_run), "--top", "1", "--episodes",
                          "1", "--steps", "5"], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    rows = [line.split() for line in res.stdout.splitlines()[1:]]
    assert [r[0] for r in rows][0] == "nominal" and len(rows) == 2 and rows[1][0].startswith("it")
    assert 0.0 <= float(rows[0][-1]) < 10.0  # the nominal plug sits nearly upright in the hand
    (tmp_path / "grasp" / ".hydra").mkdir(parents=True)
    from omegaconf import OmegaConf

    from tests.runner.conftest import compose_run

    (tmp_path / "grasp" / ".hydra" / "config.yaml").write_text(OmegaConf.to_yaml(compose_run(["task=grasp"])))
    (tmp_path / "grasp" / "handles.json").write_text('{"handles": [0], "anchors": [1, 2, 3]}')
    (tmp_path / "grasp" / "journal.jsonl").write_text("")
    res = subprocess.run([sys.executable, "scripts/in_hand_tilt.py", str(tmp_path / "grasp")], cwd=ROOT,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 2 and "measured for insertion runs" in res.stderr and "Traceback" not in res.stderr
