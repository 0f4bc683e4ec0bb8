"""Racing and the library optimizers (issue 39): bad settings are one line and exit code 2 before any work;
the library optimizers are deterministic given budget.seed and run and resume through ``python -m grt.run``."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from grt.cli._common import exit_on_user_error
from grt.config import validate
from tests.runner._toy_run import TOY
from tests.runner.conftest import compose_run

ROOT = Path(__file__).resolve().parents[2]


def _refused(overrides: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as info, exit_on_user_error():
        validate(compose_run(overrides))
    err = capsys.readouterr().err.strip()
    assert info.value.code == 2 and len(err.splitlines()) == 1 and err.startswith("error: "), err
    return err


@pytest.mark.parametrize(("overrides", "words"), [
    (["budget.race_alpha=0.5"], ["budget.race_alpha=0.5", "[0, 0.5)"]),
    (["budget.race_rounds=1"], ["budget.race_rounds=1", ">= 2"]),
    (["budget.racing=true", "task=drawer", "policy=drawer_expert", "selector=manual"],
     ["budget.racing=true", "mean opening (m)", "budget.racing=false"]),
    (["optimizer=nevergrad", "optimizer.method=NGopt"], ["'NGopt'", "close names: NGOpt"]),
    (["optimizer=optuna_gp", "budget=smoke", "budget.iterations=1"],
     ["3 x 1 = 3 candidates", "initial design of 3", "budget.iterations=2"]),
])
def test_bad_search_settings_are_one_line(overrides, words, capsys):
    line = _refused(overrides, capsys)
    assert all(w in line for w in words), line


@pytest.mark.parametrize("option", ["nevergrad", "nevergrad_tbpsa", "optuna_gp"])
def test_library_optimizers_replay_exactly_from_their_seed(option):
    from hydra.utils import instantiate

    node = compose_run([f"optimizer={option}", "budget=smoke"]).optimizer  # 3 x 2: Optuna's 2nd is the GP's
    runs = []
    for _ in range(2):
        opt, asked = instantiate(node)(num_handles=2), []
        for _ in range(2):
            theta = opt.ask()
            opt.tell(theta, 1.0 - np.tanh(np.abs(theta).sum(axis=(1, 2))))  # any deterministic score
            asked.append(theta)
        runs.append(np.stack(asked))
    assert np.array_equal(runs[0], runs[1]) and np.abs(runs[0]).max() > 0


def _run(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.run", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env={**os.environ, **(env or {})})


def _journal(path: Path) -> list[dict]:
    return [json.loads(line) for line in (path / "journal.jsonl").read_text().splitlines()]


@pytest.mark.slow
@pytest.mark.parametrize("option", ["nevergrad", "optuna_gp"])
def test_a_library_optimizer_with_racing_resumes_after_a_kill_with_nothing_repeated(option, tmp_path):
    """End to end (toy scores, no simulator): the run whole, and the same run stopped by Ctrl-C at its first
    simulated candidate then resumed by ``python -m grt.run resume=DIR``: the same journal, nothing evaluated
    twice; the summary counts the trials and the raced candidates."""
    from grt.runner import run

    args = ["budget=smoke", f"optimizer={option}", "budget.racing=true", "budget.trials=4", "budget.sigma=0.03",
            "budget.iterations=3", "object=can", "selector.k=3", *TOY]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    run(compose_run([*args, f"paths.output_dir={whole}"]))  # in this process: one interpreter start less
    first = _run(*args, f"hydra.run.dir={cut}", env={"GRT_TEST_INTERRUPT_AT": "2"})  # at the 1st candidate
    assert first.returncode == 130, first.stderr[-2000:]
    done = len(_journal(cut))
    assert 1 <= done < len(_journal(whole))
    proc = _run(f"resume={cut}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    keep = ("iteration", "candidate", "theta", "score", "race", "trials")
    assert [{k: r.get(k) for k in keep} for r in _journal(cut)] == [{k: r.get(k) for k in keep} for r in _journal(whole)]
    summary = json.loads((cut / "summary.json").read_text())
    # nothing evaluated twice: this session simulated only the candidates after the first session's
    assert summary["evaluated_this_session"] == sum(1 for r in _journal(cut)[done:] if r["trials"])
    assert summary["trials_used"] == sum(len(r["trials"]) for r in _journal(cut))
    simulated = [r for r in _journal(cut)[1:] if r["trials"]]
    assert all(r["race"]["trials"] == len(r["trials"]) for r in simulated)
    assert summary["racing"]["stopped"] + summary["racing"]["full"] == len(simulated)


def test_racing_asked_of_an_evaluator_that_cannot_race_is_recorded_as_nothing_raced(tmp_path):
    """budget.racing=true on an evaluator that runs every trial of a candidate: the log says so, and the
    summary neither labels the run as raced nor counts trials it did not save; its note says why."""
    from grt.report.tables import method
    from grt.runner import run

    args = ["budget=smoke", "budget.racing=true", "budget.trials=4", "budget.sigma=0.03", "budget.iterations=1",
            "object=can", "selector.k=3", *TOY, "+evaluator.races=false", f"paths.output_dir={tmp_path}"]
    summary = run(compose_run(args))
    assert "racing" not in summary and "nothing was raced" in summary["note"]
    assert all("race" not in r and len(r["trials"]) == 4 for r in _journal(tmp_path) if r["trials"])
    assert "racing" not in method(summary)
