"""grt.report's margins table and plot tell a search for the smallest CrashShape from the plain search."""

from __future__ import annotations

import pytest

from grt.report.margins import margins_markdown, plot_margins

SHRINK = {"shapes": [{"largest_mm": 2.1, "alpha": 0.24, "sigma_equivalent": 0.0151, "rank": 2}]}


def _row(tmp_path, name: str, **extra) -> dict:
    folder = tmp_path / name
    folder.mkdir()
    (folder / "summary.json").write_text("{}")
    return {"task": "insertion", "object": "usb_plug", "policy": "insertion_state", "s0": 1.0,
            "file": str(folder / "summary.json"), "shrink": SHRINK, **extra}


def test_a_size_penalised_run_is_labelled_in_the_margins_table(tmp_path):
    table = margins_markdown([_row(tmp_path, "plain"), _row(tmp_path, "size", size_penalty=1.0)])
    rows = [ln for ln in table.splitlines() if ln.startswith("| insertion |")]
    assert [r.split(" | ")[2] for r in rows] == ["insertion_state", "insertion_state (+ size 1)"]
    assert "(α 0.24, σ 0.0151; rank 2 of 1)" in rows[1]


def test_the_margins_plot_needs_a_profile(tmp_path):
    with pytest.raises(ValueError, match="no run with a profile"):
        plot_margins([_row(tmp_path, "plain")], tmp_path / "m.png")
    assert not (tmp_path / "m.png").exists()
