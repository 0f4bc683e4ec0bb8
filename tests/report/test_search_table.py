"""The search benchmark's table and plot (grt/report/search.py) and the trial counts a run's summary carries
(grt.racing.search_figures)."""

from __future__ import annotations

import json

from grt.racing import search_figures
from grt.report.tables import render


def _summary(optimizer, racing, seed, used, drop, first):
    return {"task": "grasp", "object": "mug", "policy": "antipodal", "selector": "heuristic", "optimizer": optimizer,
            "seed": seed, "final_drop": drop, "delta_complexity": 0.05, "iter_at_50": 2, "auc": drop * 3, "s0": 1.0,
            "best_score": 1 - drop, "trials_used": used, "trials_curve": [8, used // 2, used],
            "curve": [0.0, drop / 2, drop], "trials_to_first_confirmed": first,
            **({"racing": {"stopped": 3, "full": 3}} if racing else {})}


def test_the_search_table_pairs_each_method_with_the_baseline_and_plots_against_trials(tmp_path):
    for seed in (0, 1):
        for name, opt, racing, used, first in (("base", "topdm", False, 200, 100), ("race", "topdm", True, 100, 60),
                                               ("cma", "cma_es", True, 150, None)):
            (tmp_path / f"summary_mug_{name}_s{seed}.json").write_text(json.dumps(
                _summary(opt, racing, seed, used + seed * 10, 0.5 + 0.1 * seed, first)))
    text = render(tmp_path).split("Simulator trials per method")[1]
    rows = {line.split(" | ")[2]: line for line in text.splitlines() if line.startswith("| grasp | antipodal |")}
    assert set(rows) == {"topdm", "topdm + racing", "cma_es + racing"}
    assert "0.51 [0.36, 0.66] (n=2)" in rows["topdm + racing"]  # about half the baseline's trials, run by run
    assert "- (0/2)" in rows["cma_es + racing"]  # no confirmed CrashShape in either run
    assert "60 (2/2)" in rows["topdm + racing"]
    from grt.cli.report import main

    main([str(tmp_path), "--search-plot", str(tmp_path / "search.png")])
    assert (tmp_path / "search.png").stat().st_size > 10_000


def test_search_figures_count_the_trials_each_candidate_ran():
    records = [{"iteration": 0, "candidate": 0, "trials": [1] * 4},
               {"iteration": 1, "candidate": 0, "trials": [1] * 2}, {"iteration": 1, "candidate": 1, "trials": []},
               {"iteration": 2, "candidate": 0, "trials": [1] * 4}, {"iteration": 2, "candidate": 1, "trials": [1] * 4}]
    confirm = {"shapes": [{"iteration": 2, "candidate": 1, "confirmed": True},
                          {"iteration": 2, "candidate": 0, "confirmed": False}]}
    got = search_figures(records, confirm)
    assert got == {"trials_used": 14, "trials_curve": [4, 6, 14], "trials_to_first_confirmed": 14,
                   "trials_to_first_crash": 10}


def test_an_interval_stays_within_what_the_figure_can_be(tmp_path):
    for seed, drop in enumerate((0.0, 1.0, 1.0)):  # three runs: a t-interval of the mean is [-77, 210]%
        (tmp_path / f"summary_mug_base_s{seed}.json").write_text(json.dumps(
            _summary("topdm", False, seed, 100, drop, None)))
    text = render(tmp_path).split("Simulator trials per method")[1]
    row = next(line for line in text.splitlines() if line.startswith("| grasp | antipodal | topdm |"))
    assert "66.7 [0.0, 100.0]" in row  # the Final Drop column: a percentage of S0
    assert "2.00 [0.00," in row  # AUC: not below zero either
