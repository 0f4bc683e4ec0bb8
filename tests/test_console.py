"""grt.console: in a log (not a TTY) progress is plain lines and rich output is not wrapped at 80 columns."""

from __future__ import annotations

import io
import time

from rich.table import Table

from grt.console import LineProgress, console, progress


def test_progress_in_a_log_is_plain_lines_at_each_tenth_with_an_average_rate_and_a_steady_eta():
    out = io.StringIO()
    bar = progress(20, "red-team", "cand", file=out)
    assert isinstance(bar, LineProgress)  # a StringIO is no terminal
    bar.update(1)
    assert out.getvalue() == ""  # 1/20 is not yet a tenth
    bar.update(1)
    time.sleep(0.01)
    bar.set_postfix(it=1, score="0.50")
    bar.update(1)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("red-team: 2/20 (10%)") and "cand/s" in lines[0] and "ETA" in lines[0], lines
    assert len(lines) == 1  # 3/20 (15%) is still the tenth already reported
    for _ in range(17):
        bar.update(1)
    bar.close()
    bar.close()  # idempotent
    lines = out.getvalue().splitlines()
    assert len(lines) == 10 and "\r" not in out.getvalue(), lines
    assert lines[-1].startswith("red-team: 20/20 (100%)") and "ETA" not in lines[-1] and "cand/s" in lines[-1]
    assert lines[-1].endswith("it=1 score=0.50")


def test_the_first_line_has_no_eta_and_a_resumed_count_is_not_in_the_rate():
    out = io.StringIO()
    bar = LineProgress(4, "trials", "trial", initial=2, file=out)
    bar.update(1)  # 3/4: a new tenth, the first unit: no steady rate yet
    assert "ETA" not in out.getvalue() and out.getvalue().startswith("trials: 3/4 (75%)")
    assert bar.n - bar.initial == 1


def test_a_console_in_a_log_keeps_tables_and_paths_whole():
    out = io.StringIO()
    path = "/a/very/long/" + "folder/" * 20 + "curve.png"
    table = Table(title="t")
    for col in ("S0", "best", "Final Drop", "Iter@50%", "AUC", "ΔComplexity", "evals", "wall s", "more", "still"):
        table.add_column(col)
    table.add_row(*["0.123456789"] * 10)
    c = console(out)
    c.print(table)
    c.print(f"run folder: {path}")
    text = out.getvalue()
    assert "ΔComplexity" in text and path in text and "…" not in text, text
