"""Scores are named by the task: "success rate" for binary tasks, "mean opening (m)" for a drawer."""

from __future__ import annotations

import csv
import json
import shutil

import pytest
from omegaconf import OmegaConf

from grt.blueteam.core import write_table
from grt.cli._common import find_user_error
from grt.cli.report import main
from grt.outputs import print_summary
from grt.report.plots import curve_figure
from grt.report.tables import collect, markdown
from grt.scores import ScoreConfigError, ScoreSpec

OPENING = ScoreSpec(name="opening", unit="m")


def test_spec_from_task_configs_old_and_new():
    assert ScoreSpec.from_task({"score": "success"}) == ScoreSpec("success", "", "auto")
    assert ScoreSpec.from_task({}) == ScoreSpec()  # run configs written before these keys
    drawer = OmegaConf.create({"score": "opening", "score_unit": "m", "ci": "bootstrap"})
    assert ScoreSpec.from_task(drawer) == ScoreSpec("opening", "m", "bootstrap")
    assert ScoreSpec.from_task({"score": "opening", "score_unit": None, "ci": None}) == ScoreSpec("opening")


def test_labels_and_formats():
    assert ScoreSpec().label == "success rate" and ScoreSpec().binary
    assert OPENING.label == "mean opening (m)" and OPENING.title == "mean opening" and not OPENING.binary
    assert ScoreSpec(name="reward").label == "mean reward"
    assert ScoreSpec().fmt(0.8125) == "0.81" and ScoreSpec().fmt(0.8125, unit=True) == "0.81"
    assert OPENING.fmt(0.35) == "0.35" and OPENING.fmt(0.123456, unit=True) == "0.1235 m"
    assert OPENING.fmt(float("nan")) == "-" and OPENING.fmt(None) == "-"
    assert OPENING.fields() == {"score_name": "opening", "score_unit": "m", "ci": "auto"}


def test_bad_ci_settings_are_user_errors_naming_the_key():
    with pytest.raises(ScoreConfigError, match="task.ci='student'") as info:
        ScoreSpec.from_task({"ci": "student"})
    assert find_user_error(info.value) is info.value  # one line and exit code 2 in the CLIs
    with pytest.raises(ScoreConfigError, match="in m: use task.ci=normal, bootstrap or auto"):
        ScoreSpec.from_task({"score": "opening", "score_unit": "m", "ci": "wilson"})


def test_curve_is_labelled_with_the_score():
    import matplotlib.pyplot as plt

    fig = curve_figure(0.35, [[0.30, 0.34], [0.12]], score=OPENING)
    ax = fig.axes[0]
    assert ax.get_ylabel() == "mean opening (m)"
    assert "nominal S0 = 0.35 m" in [t.get_text() for t in ax.get_legend().get_texts()]
    plt.close(fig)
    fig = curve_figure(0.9, [[0.8]])
    assert fig.axes[0].get_ylabel() == "success rate"
    plt.close(fig)


def _summary(folder, obj: str, s0: float, best: float, **extra) -> None:
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(json.dumps({
        "task": "drawer" if extra else "grasp", "object": obj, "selector": "heuristic", "optimizer": "topdm",
        "s0": s0, "best_score": best, "final_drop": (s0 - best) / s0, "delta_complexity": 0.01,
        "iter_at_50": 2, "reached_50": True, "auc": 1.2, "evaluations": 11, "wall_s": 5.0, **extra}))


def test_report_names_each_runs_score(tmp_path, capsys):
    _summary(tmp_path / "old", "mug", 0.9, 0.3)  # a summary written before score_name: a success rate
    _summary(tmp_path / "drawer", "cabinet", 0.35, 0.05, score_name="opening", score_unit="m", ci="auto")
    rows, failed = collect(tmp_path)
    table = markdown(rows, [], failed)
    assert "| drawer | cabinet | - | heuristic + topdm | - | - | mean opening (m) | - | 0.35 | 0.05 | 85.7 |" in table
    assert "| grasp | mug | - | heuristic + topdm | - | - | success rate | - | 0.900 | 0.300 | 66.7 |" in table
    _summary(tmp_path / "new", "bowl", 0.8, 0.4, sigma=0.01, seed=7, score_name="success")  # sigma, seed
    assert "| drawer | bowl | - | heuristic + topdm | 0.01 | 7 | success rate | - | 0.800 |" in markdown(
        collect(tmp_path)[0], [], [])
    main([str(tmp_path), "--csv", str(tmp_path / "t.csv")])
    assert "mean opening (m)" in capsys.readouterr().out
    with open(tmp_path / "t.csv") as f:
        by_object = {r["object"]: r for r in csv.DictReader(f)}
    assert (by_object["cabinet"]["score_name"], by_object["cabinet"]["score_unit"]) == ("opening", "m")
    assert (by_object["mug"]["score_name"], by_object["mug"]["score_unit"]) == ("success", "")


def test_report_reads_kept_copies_and_keeps_sigmas_apart(tmp_path, capsys):
    """experiments/ keeps summaries as summary_<name>.json side by side; the mean never mixes two σ."""
    for name, sigma, best in (("mug_a", 0.06, 0.0), ("bottle_a", 0.06, 0.45), ("mug_b", 0.001, 0.81)):
        (tmp_path / f"summary_{name}.json").write_text(json.dumps({
            "task": "grasp", "object": name.split("_")[0], "selector": "heuristic", "optimizer": "topdm",
            "sigma": sigma, "s0": 0.9, "best_score": best, "final_drop": (0.9 - best) / 0.9,
            "delta_complexity": 0.01, "iter_at_50": 1, "reached_50": True, "auc": 1.0, "evaluations": 11}))
    (tmp_path / "summary_notes.txt").write_text("not a summary")
    main([str(tmp_path)])
    out = capsys.readouterr().out
    assert "| grasp | - | heuristic + topdm | 0.06 | 2 | - | 75.0 |" in out  # (100 + 50) / 2
    assert "| grasp | - | heuristic + topdm | 0.001 | 1 | - | 10.0 |" in out


def test_console_summary_names_the_score(tmp_path, capsys):
    summary = {"task": "drawer", "object": "cabinet", "selector": "heuristic", "optimizer": "topdm",
               "score_name": "opening", "score_unit": "m", "s0": 0.35, "best_score": 0.05,
               "final_drop": 6 / 7,
               "iter_at_50": 2, "reached_50": True, "auc": 1.23, "delta_complexity": 0.2, "evaluations": 11,
               "wall_s": 3.0}
    print_summary(summary, tmp_path)
    out = capsys.readouterr().out
    assert "0.35 m" in out and "0.05 m" in out and "mean opening (m)" in out and "85.7%" in out


def test_an_unreached_iter_at_50_reads_as_not_reached_not_as_an_iteration(toy_run, tmp_path, capsys):
    """Iter@50% is the budget T when the drop never reached 50%: ``2 (not reached)`` read as "at 2" (issue 40)."""
    from grt.report.html import render_run

    summary = {"task": "grasp", "object": "mug", "selector": "heuristic", "optimizer": "topdm", "s0": 0.5,
               "best_score": 0.4, "final_drop": 0.2, "iter_at_50": 2, "reached_50": False, "auc": 0.3,
               "delta_complexity": 0.1, "evaluations": 7, "wall_s": 3.0}
    print_summary(summary, tmp_path)
    out = capsys.readouterr().out
    assert "not reached in 2" in out and "(not reached)" not in out
    run = tmp_path / "run"
    shutil.copytree(toy_run, run)
    on_disk = json.loads((run / "summary.json").read_text())
    (run / "summary.json").write_text(json.dumps({**on_disk, "iter_at_50": 2, "reached_50": False}))
    page = render_run(run)
    assert "<td>not reached in 2</td>" in page and "(not reached)" not in page


def test_blue_team_table_names_the_score(tmp_path):
    row = {"policy": "p", "geometry": "it1_c0", "orig": 0.05, "blue": 0.31, "nominal_before": 0.35,
           "nominal_after": 0.34, "heldout_before": 0.1, "heldout_after": 0.3}
    write_table(tmp_path, [row], OPENING)
    text = (tmp_path / "table3.md").read_text()
    assert text.startswith("Scores: mean opening (m),")
    assert "| p | it1_c0 | 0.05 | 0.31 | 0.35 | 0.34 |" in text
    write_table(tmp_path, [{**row, "orig": 0.25, "blue": 0.75}], "success")  # the name alone, as before
    text = (tmp_path / "table3.md").read_text()
    assert text.startswith("Scores: success %,") and "| 25.0 | 75.0 |" in text
