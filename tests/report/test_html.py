"""report.html of a run folder and of a sweep, and what it says about a damaged folder."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

from grt.report.html import write_report

ROOT = Path(__file__).resolve().parents[2]


def report(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.report", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def meshes(page: str) -> dict:
    return json.loads(re.search(r"window\.GRT_MESHES = (\{.*?\});", page, re.S).group(1))


def test_the_run_writes_a_self_contained_report(toy_run):
    page = (toy_run / "report.html").read_text()
    summary = json.loads((toy_run / "summary.json").read_text())
    # nothing fetched from anywhere: no external script, stylesheet, image or font
    assert not re.search(r"""(src|href)=['"](https?:)?//""", page)
    assert page.count("function colormap") == 1, "the viewer is embedded once per page"
    for metric in ("S0", "Final Drop", "Iter@50%", "AUC", "ΔComplexity", "Confirmed drop", "Holm p",
                   "noise floor of Final Drop"):
        assert metric in page, metric
    # the confirmed drop leads the headline; the noise floor sits beside Final Drop
    assert page.index(">Confirmed drop<") < page.index(">S0<") < page.index(">Final Drop<") \
        < page.index(">noise floor of Final Drop<") < page.index(">Iter@50%<")
    assert f"{100 * summary['final_drop']:.1f}" in page
    assert summary["git"]["commit"] in page and summary["machine"]["python"] in page
    assert "remeshed" in page  # the mesh-preparation record
    assert "budget:" in page and "sigma: 0.06" in page  # the resolved config


def test_crashshapes_are_embedded_with_their_displacement_in_mm(toy_run):
    page = (toy_run / "report.html").read_text()
    summary = json.loads((toy_run / "summary.json").read_text())
    found = meshes(page)
    assert set(found) == {"nominal"} | {f"rank{s['rank']}" for s in summary["crashshapes"]}
    import trimesh

    nominal = trimesh.load(toy_run / "nominal.obj", process=False, force="mesh")
    shape = summary["crashshapes"][0]
    mesh = trimesh.load(toy_run / shape["file"].replace(".stl", ".obj"), process=False, force="mesh")
    disp = np.frombuffer(base64.b64decode(found["rank1"]["values"]), np.float32)
    expected = 1000 * np.linalg.norm(mesh.vertices - nominal.vertices, axis=1)
    assert np.allclose(disp, expected, atol=1e-3)
    handles = json.loads((toy_run / "handles.json").read_text())["handles"]
    assert found["rank1"]["handles"] == handles
    assert f"href='{shape['file']}'" in page  # the printable STL
    assert f"volume {shape['volume_change']:+.1%} vs nominal" in page  # issue 33: shape change beside the view


def test_failure_modes_and_seeds_of_every_trial_are_shown(toy_run):
    page = (toy_run / "report.html").read_text()
    journal = [json.loads(line) for line in (toy_run / "journal.jsonl").read_text().splitlines()]
    nominal = journal[0]
    for t in nominal["trials"]:
        assert f"<td>{t['seed']}</td>" in page
    shape = json.loads((toy_run / "summary.json").read_text())["crashshapes"][0]
    rec = next(r for r in journal if (r["iteration"], r["candidate"]) == (shape["iteration"], shape["candidate"]))
    fails = sum(t["mode"] == "missed" for t in rec["trials"])
    assert fails > 0, "the toy policy should fail on the rank-1 shape"
    assert f"<title>missed: {fails} of {len(rec['trials'])}</title>" in page


def test_each_mode_shown_is_explained_where_it_is_shown(run_copy):
    """Beside the modes' bars and under each video, what each mode means, from the task module's docstring
    (issue 40: a video of an unreachable grasp showed a robot that never moves, and nothing said why)."""
    import html

    from grt.rerun import write_video
    from grt.tasks.base import mode_meanings

    config = run_copy / "run_config.yaml"  # the toy run as a grasp run: its modes are the grasp task's
    config.chmod(0o644)
    config.write_text(config.read_text().replace("tests.runner._toy_run.ToyTaskSession", "grt.tasks.grasp.GraspSession"))
    shape = json.loads((run_copy / "summary.json").read_text())["crashshapes"][0]
    name = f"it{shape['iteration']}_c{shape['candidate']}_seed7.mp4"
    write_video([np.full((32, 32, 3), 90, np.uint8)] * 4, run_copy / "videos" / name, fps=10)
    clip = {"file": name, "label": "CrashShape", "mode": "unreachable", "journal_mode": "unreachable"}
    (run_copy / "videos" / "videos.json").write_text(json.dumps({"pairs": [{"title": "rank 1", "seed": 7,
                                                                            "clips": [clip]}]}))
    page = write_report(run_copy)[0].read_text()
    meanings = mode_meanings("grt.tasks.grasp.GraspSession")
    modes = page[page.index("id='modes'"):page.index("id='videos'")]
    for mode in ("missed", "success"):  # the toy run's modes
        assert f"<b class='{'' if mode == 'success' else 'mode-bad'}'>{mode}</b>: {html.escape(meanings[mode])}" \
            in modes, mode
    videos = page[page.index("id='videos'"):]
    assert html.escape(meanings["unreachable"]) in videos and "never moved" in meanings["unreachable"]


def test_a_sweep_page_links_each_runs_page(toy_run, tmp_path):
    for name in ("a", "b"):
        shutil.copytree(toy_run, tmp_path / "sweep" / name)
    write_report(tmp_path / "sweep")
    page = (tmp_path / "sweep" / "report.html").read_text()
    assert "href='a/report.html'" in page and "href='b/report.html'" in page
    assert (tmp_path / "sweep" / "a" / "report.html").is_file()


def test_a_folder_that_is_not_a_run_is_one_line_and_exit_2(tmp_path):
    proc = report(tmp_path, "--html")
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "not a GRT run" in proc.stderr and "Traceback" not in proc.stderr


def test_a_run_killed_mid_way_is_reported_as_partial(run_copy):
    (run_copy / "summary.json").unlink()
    lines = (run_copy / "journal.jsonl").read_text().splitlines(keepends=True)
    (run_copy / "journal.jsonl").write_text("".join(lines[:4]) + lines[4][:30])  # killed while writing a line
    write_report(run_copy)
    page = (run_copy / "report.html").read_text()
    assert "(partial)" in page and "4 candidate(s) in the journal of 7 planned" in page
    assert "last line is cut" in page
    assert (run_copy / "journal.jsonl").read_text().endswith(lines[4][:30]), "a report changes no run file"


def test_deleted_meshes_are_named_and_the_others_rendered(run_copy):
    shapes = json.loads((run_copy / "summary.json").read_text())["crashshapes"]
    gone = shapes[0]["file"]
    (run_copy / gone).unlink()
    (run_copy / gone.replace(".stl", ".obj")).unlink()
    proc = report(run_copy, "--html")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"wrote {run_copy / 'report.html'}"
    page = (run_copy / "report.html").read_text()
    assert f"not shown: {gone}" in page
    assert set(meshes(page)) == {"nominal", *(f"rank{s['rank']}" for s in shapes[1:])}


def test_without_a_renderer_the_page_says_why_in_one_line(run_copy, monkeypatch):
    import grt.rerun

    why = "no working renderer on this machine (RuntimeError: no Vulkan device)"
    monkeypatch.setattr(grt.rerun, "renderer_problem", lambda: why)
    summary = json.loads((run_copy / "summary.json").read_text())
    index = grt.rerun.render_videos(run_copy, summary, 2)
    assert index["skipped"] == why and index["pairs"] == []
    write_report(run_copy)
    page = (run_copy / "report.html").read_text()
    assert f"<p class='warn'>No videos: {why}</p>" in page and "<video" not in page


def test_refused_candidates_written_null_by_the_journal_are_read_as_nan(tmp_path):
    """The journal writes a refused candidate's NaN score as strict JSON (null + its ``nonfinite`` key);
    the report reads it back as NaN and draws it as refused, not as a score (found on the demo's run)."""
    import math

    from grt.journal import strict
    from grt.report.html import read_journal, search_svg
    from grt.scores import ScoreSpec

    lines = [{"iteration": 0, "candidate": 0, "score": 1.0}, {"iteration": 1, "candidate": 0, "score": 0.5},
             {"iteration": 1, "candidate": 1, "score": float("nan"), "valid": False}]
    path = tmp_path / "journal.jsonl"
    path.write_text("".join(json.dumps(strict(rec), allow_nan=False) + "\n" for rec in lines))
    records, problem = read_journal(path)
    assert problem is None and math.isnan(records[2]["score"]) and "nonfinite" not in records[2]
    assert "<svg" in search_svg(records, ScoreSpec())


def test_the_final_drops_interval_is_a_drop_between_0_and_100_percent():
    """A best candidate whose interval reached above S0 printed the drop's interval as [-31.5, 100.0]."""
    from grt.report.html import RunFolder, headline
    from grt.scores import ScoreSpec

    summary = {"s0": 0.6, "s0_ci95": [0.3, 0.85], "best_score": 0.4, "best_ci95": [0.0, 0.789], "final_drop": 1 / 3}
    rows = headline(RunFolder(Path("."), summary, [], ""), ScoreSpec.from_summary(summary))
    drop = next(r for r in rows if r[0] == "Final Drop")
    assert drop[1] == "33.3" and drop[2] == "[0.0, 100.0]", drop
