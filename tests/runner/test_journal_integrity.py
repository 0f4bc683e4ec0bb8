"""The journal is evidence, not input: an edited, removed or reordered line is refused with its line
number (a resume would otherwise rewrite the run's results from scores no simulation produced).
Old journals without checksums still load; a write cut by a kill is still dropped; the run's output
files are replaced atomically and stale CrashShapes do not survive a rewrite.
"""

from __future__ import annotations

import json
import logging
import re

import numpy as np
import pytest
import trimesh

from grt.cli._common import find_user_error
from grt.config import make_plan
from grt.fileio import atomic_path, write_text_atomic
from grt.journal import Journal, JournalError
from grt.outputs import save_crashshapes, write_outputs
from tests.runner.conftest import compose_run
from tests.runner.test_resume_checks import make_loop

REFUSED = "journal line {n} was modified or corrupted"


def _write(path, n=4):
    j = Journal(path)
    for i in range(n):
        j.append({"iteration": min(i, 1), "candidate": max(i - 1, 0), "score": 0.5 + i / 10,
                  "theta": [[0.1 * i, 0.0, -0.2]], "trials": [{"seed": 3, "score": 0.5}]})
    return path.read_text().splitlines()


def _edit(path, n, **changes):
    """Change fields of line ``n`` (1-based), keeping its stored checksum (a hand edit)."""
    lines = path.read_text().splitlines()
    lines[n - 1] = json.dumps({**json.loads(lines[n - 1]), **changes})
    path.write_text("\n".join(lines) + "\n")


def test_each_line_carries_a_checksum_chained_to_the_previous_one(tmp_path):
    path = tmp_path / "journal.jsonl"
    lines = _write(path)
    sums = [json.loads(x)["sha256"] for x in lines]
    assert len(set(sums)) == 4 and all(re.fullmatch(r"[0-9a-f]{64}", s) for s in sums)
    j = Journal(path)
    assert len(j) == 4 and j.unchecked_lines == 0
    assert "sha256" not in j.get(1, 0)  # records read back as they were appended
    j.append({"iteration": 2, "candidate": 0, "score": 0.1})
    assert len(Journal(path)) == 5


def test_edited_score_in_the_last_line_is_refused_with_its_line(tmp_path):
    path = tmp_path / "journal.jsonl"
    _write(path)
    _edit(path, 4, score=0.0)
    with pytest.raises(JournalError, match=REFUSED.format(n=4)) as err:
        Journal(path)
    assert "\n" not in str(err.value) and "truncate -s" in str(err.value) and "new run" in str(err.value)
    assert find_user_error(err.value) is err.value  # the CLIs: one line, exit code 2


@pytest.mark.parametrize("change", [{"score": 0.0}, {"theta": [[0.0, 0.0, 0.0]]}, {"sha256": "0" * 64}])
def test_any_edit_of_an_earlier_line_is_refused_naming_that_line(tmp_path, change):
    path = tmp_path / "journal.jsonl"
    _write(path)
    _edit(path, 2, **change)
    with pytest.raises(JournalError, match=REFUSED.format(n=2)):
        Journal(path)


def test_removed_reordered_or_unsealed_lines_are_refused(tmp_path):
    path = tmp_path / "journal.jsonl"
    lines = _write(path)
    path.write_text("\n".join([lines[0], lines[2], lines[3]]) + "\n")  # line 2 deleted
    with pytest.raises(JournalError, match=REFUSED.format(n=2)):
        Journal(path)
    path.write_text("\n".join([lines[0], lines[2], lines[1], lines[3]]) + "\n")
    with pytest.raises(JournalError, match=REFUSED.format(n=2)):
        Journal(path)
    rec = json.loads(lines[2])
    del rec["sha256"]  # a checksum removed after checked lines: not an old journal
    path.write_text("\n".join([lines[0], lines[1], json.dumps(rec), lines[3]]) + "\n")
    with pytest.raises(JournalError, match=REFUSED.format(n=3)):
        Journal(path)


def test_damaged_bytes_in_an_earlier_line_are_refused_naming_that_line(tmp_path):
    path = tmp_path / "journal.jsonl"
    lines = _write(path, n=3)
    path.write_bytes(b"\n".join([lines[0].encode(), b"\xff\xfe" + lines[1].encode(), lines[2].encode()]) + b"\n")
    with pytest.raises(JournalError, match=REFUSED.format(n=2)):
        Journal(path)


def test_a_run_with_an_edited_earlier_iteration_is_refused_as_an_edit_not_a_config_change(tmp_path):
    loop, _ = make_loop(tmp_path)
    first = loop.run()
    path = tmp_path / "journal.jsonl"
    _edit(path, 3, score=0.0)  # iteration 1, candidate 1
    with pytest.raises(JournalError, match=REFUSED.format(n=3)) as err:
        make_loop(tmp_path)
    assert "config" not in str(err.value)
    # The way out the message gives: keep the lines before it and resume, which re-evaluates the rest.
    offset = int(re.search(r"truncate -s (\d+) ", str(err.value)).group(1))
    with open(path, "r+b") as f:
        f.truncate(offset)
    again, ev = make_loop(tmp_path)
    second = again.run()
    assert ev.calls == len(first.records) - 2 and second.iteration_scores == first.iteration_scores


def test_old_journal_without_checksums_loads_unchecked_and_takes_checked_appends(tmp_path, caplog):
    path = tmp_path / "journal.jsonl"
    path.write_text('{"iteration": 0, "candidate": 0, "score": 0.9}\n'
                    '{"iteration": 1, "candidate": 0, "score": 0.5, "ci95": [NaN, NaN]}\n')
    with caplog.at_level(logging.WARNING, logger="grt.journal"):
        j = Journal(path)
    assert len(j) == 2 and j.unchecked_lines == 2 and j.get(1, 0)["score"] == 0.5
    assert len([r for r in caplog.records if "checksums" in r.getMessage()]) == 1
    j.append({"iteration": 1, "candidate": 1, "score": 0.4})
    j2 = Journal(path)
    assert len(j2) == 3 and j2.unchecked_lines == 2
    _edit(path, 1, score=0.0)  # the checked line seals the unchecked ones before it
    with pytest.raises(JournalError, match=REFUSED.format(n=3)):
        Journal(path)


def test_truncated_last_line_is_still_dropped_and_the_chain_goes_on(tmp_path):
    path = tmp_path / "journal.jsonl"
    lines = _write(path, n=2)
    with open(path, "a") as f:  # a write killed half-way
        f.write('{"iteration": 1, "candidate": 1, "sco')
    j = Journal(path)
    assert j.recovered_truncated_line and len(j) == 2
    assert path.read_text().splitlines() == lines
    j.append({"iteration": 1, "candidate": 1, "score": 0.4})
    j2 = Journal(path)
    assert not j2.recovered_truncated_line and j2.get(1, 1)["score"] == 0.4


def test_records_with_tuples_int_keys_and_nan_verify_after_a_reload(tmp_path):
    path = tmp_path / "journal.jsonl"
    Journal(path).append({"iteration": 0, "candidate": 0, "score": float("nan"), "ci95": (0.1, 0.2),
                          "outcomes": {10: 1, 9: 2}, "x": np.float64(0.1) + 0.2})
    rec = Journal(path).get(0, 0)
    assert rec["ci95"] == [0.1, 0.2] and rec["outcomes"] == {"10": 1, "9": 2} and rec["x"] == 0.1 + 0.2


class _Parts:
    def collision_parts(self, mesh):
        return [np.asarray(mesh.vertices)]


def _temp_files(folder):
    return [p for p in folder.rglob("*") if ".tmp" in p.name]


def test_rewriting_crashshapes_removes_stale_ranks_and_leaves_no_temp_files(tmp_path):
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    first = [{"iteration": 2, "candidate": 1, "score": 0.1}, {"iteration": 1, "candidate": 0, "score": 0.2}]
    save_crashshapes(tmp_path, first, [box, box], _Parts(), scale=0.001)  # also rank*_mm.stl / .obj
    out = tmp_path / "crashshapes"
    (out / "notes.txt").write_text("mine")  # not a CrashShape: left alone
    (out / "rank1_it2_c1_parts" / "part07.obj").write_text("stale part")
    (out / ".rank1_it2_c1.0badcafe.tmp.stl").write_text("left by a kill -9 mid-write")
    second = [{"iteration": 3, "candidate": 0, "score": 0.0}, {"iteration": 2, "candidate": 1, "score": 0.1}]
    saved = save_crashshapes(tmp_path, second, [box, box], _Parts())
    names = sorted(p.name for p in out.iterdir())
    assert names == ["README.txt", "notes.txt", "rank1_it3_c0.obj", "rank1_it3_c0.stl", "rank1_it3_c0_parts",
                     "rank2_it2_c1.obj", "rank2_it2_c1.stl", "rank2_it2_c1_parts"]
    assert [s["file"] for s in saved] == ["crashshapes/rank1_it3_c0.stl", "crashshapes/rank2_it2_c1.stl"]
    assert trimesh.load(out / "rank1_it3_c0.stl").is_watertight
    assert sorted(p.name for p in (out / "rank1_it3_c0_parts").iterdir()) == ["part00.obj"]
    assert _temp_files(tmp_path) == []


def test_atomic_write_keeps_the_old_file_when_the_writer_fails(tmp_path):
    path = tmp_path / "summary.json"
    write_text_atomic(path, '{"old": 1}')
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text('{"half')
        raise RuntimeError("killed while writing")
    assert path.read_text() == '{"old": 1}' and _temp_files(tmp_path) == []


def test_write_outputs_rewrite_matches_the_summary_and_leaves_no_temp_files(tmp_path):
    cfg = compose_run(["object=can", "budget=smoke", "budget.top_k=2", f"paths.output_dir={tmp_path}"])
    loop, ev = make_loop(tmp_path)
    result = loop.run()
    first = write_outputs(make_plan(cfg), result, loop.deformer, _handles(loop), ev, wall_s=1.0)
    found = first["crashshape_found"]  # no failure: the best candidates are written to best/ instead
    folder, key, other = ("crashshapes", "crashshapes", "best") if found else ("best", "best_candidates", "crashshapes")
    for name in (folder, other):  # an earlier session's rank 1 and parts, in either folder
        (tmp_path / name).mkdir(exist_ok=True)
        (tmp_path / name / "rank1_it9_c9.stl").write_text("stale")
        (tmp_path / name / "rank3_it1_c2_parts").mkdir(exist_ok=True)
    summary = write_outputs(make_plan(cfg), result, loop.deformer, _handles(loop), ev, wall_s=1.0)
    stls = sorted(p.relative_to(tmp_path).as_posix() for p in (tmp_path / folder).glob("*.stl"))
    assert stls == sorted(s["file"] for s in summary[key])
    assert not (tmp_path / folder / "rank3_it1_c2_parts").exists() and not list((tmp_path / other).glob("rank*"))
    assert json.loads((tmp_path / "summary.json").read_text())[key] == summary[key]
    for name in ("curve.png", "shapes.png", f"{folder}/handles.json"):
        assert (tmp_path / name).stat().st_size > 0
    assert _temp_files(tmp_path) == []


def _handles(loop):
    from grt.selectors.base import HandleSet

    return HandleSet(handles=loop.deformer.handles, anchors=loop.deformer.anchors, notes={})


def _strict_json(line: str) -> dict:
    def refuse(constant):
        raise ValueError(f"{constant} is not strict JSON")

    return json.loads(line, parse_constant=refuse)


def test_a_nan_score_is_written_as_strict_json_and_reads_back_as_nan(tmp_path):
    from grt.journal import chain_checksum

    path = tmp_path / "journal.jsonl"
    j = Journal(path)
    implausible = {"iteration": 1, "candidate": 0, "score": float("nan"), "ci95": [float("nan"), float("nan")],
                   "entropy": None, "trials": [{"seed": 3, "score": float("-inf")}], "wall_s": 0.1}
    j.append({"iteration": 0, "candidate": 0, "score": 0.75, "ci95": [0.5, 0.9], "entropy": None, "trials": []})
    j.append(implausible)
    lines = path.read_text().splitlines()
    records = [_strict_json(line) for line in lines]  # any JSON reader takes every line
    assert records[1]["score"] is None and records[1]["entropy"] is None and "nonfinite" not in records[0]
    back = Journal(path).records  # checksums verified, the NaN restored where it was (not the real None)
    assert np.isnan(back[1]["score"]) and np.isnan(back[1]["ci95"]).all() and back[1]["entropy"] is None
    assert back[1]["trials"][0]["score"] == float("-inf") and back[0] == j.records[0]
    assert json.dumps(back[1], sort_keys=True) == json.dumps(j.records[1], sort_keys=True)

    old = tmp_path / "old.jsonl"  # a journal written before: bare NaN in its lines, its checksums over them
    head, out = "", []
    for rec in ({"iteration": 0, "candidate": 0, "score": 0.75}, {"iteration": 1, "candidate": 0, "score": float("nan")}):
        head = chain_checksum(head, rec)
        out.append(json.dumps({**rec, "sha256": head}, separators=(",", ":")))
    old.write_text("\n".join(out) + "\n")
    assert "NaN" in old.read_text()
    legacy = Journal(old)
    assert np.isnan(legacy.records[1]["score"]) and legacy.unchecked_lines == 0
    legacy.append({"iteration": 1, "candidate": 1, "score": float("nan")})  # continues the chain, strictly
    _strict_json(old.read_text().splitlines()[-1])
    assert len(Journal(old).records) == 3
