"""``python -m grt.replay``: one trial of a run re-run from its journal gives the journal's outcome."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def replay(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "grt.replay", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.parametrize(("args", "message"), [
    (["candidate=it1_c0"], "give candidate= and seed= together"),
    (["candidate=it9_c0", "seed=1"], "it9_c0 is not in"),
    (["candidate=nominal", "seed=1"], "seed 1 is not a trial of nominal"),
])
def test_a_wrong_trial_is_one_line_and_exit_2(toy_run, args, message):
    proc = replay(toy_run, *args)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert message in proc.stderr and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr


@pytest.mark.parametrize(("args", "message"), [
    (["candidate=first", "seed=1"], "give it<iteration>_c<index>"),
    (["seed=x", "candidate=nominal"], "an episode seed is an integer"),
    (["colour=red"], "key one of candidate, seed, video"),
    (["candidate=nominal", "seed=1", "video=out.gif"], "ending in .mp4"),
])
def test_options_are_checked_before_anything_runs(args, message):
    from grt.cli.replay import _parse
    from grt.rerun import ReplayError, parse_candidate

    with pytest.raises(ReplayError, match=re.escape(message)):
        parse_candidate(_parse(args).get("candidate", "nominal"))


def test_not_a_run_folder_is_one_line_and_exit_2(tmp_path):
    proc = replay(tmp_path)
    assert proc.returncode == 2 and "not a GRT run folder" in proc.stderr and proc.stderr.count("\n") == 1


def test_the_default_trial_is_the_rank1_shapes_first_failure(toy_run):
    from grt.rerun import first_failure

    name, seed = first_failure(toy_run)
    shape = json.loads((toy_run / "summary.json").read_text())["crashshapes"][0]
    assert name == f"it{shape['iteration']}_c{shape['candidate']}"
    rec = next(json.loads(line) for line in (toy_run / "journal.jsonl").read_text().splitlines()
               if line.startswith(f'{{"iteration":{shape["iteration"]},"candidate":{shape["candidate"]},'))
    assert seed == next(t["seed"] for t in rec["trials"] if t["mode"] != "success")


@pytest.mark.sim
@pytest.mark.slow
def test_a_replayed_trial_matches_the_journal_and_is_filmed(grasp_smoke_run, tmp_path):
    """A real (smoke) grasp run (conftest.py's, shared), then its nominal and rank-1 trials replayed in a new
    process."""
    run, _ = grasp_smoke_run
    journal = [json.loads(line) for line in (run / "journal.jsonl").read_text().splitlines()]
    summary = json.loads((run / "summary.json").read_text())
    shape = (summary["crashshapes"] or summary["best_candidates"])[0]  # a smoke run may find no CrashShape
    rec = next(r for r in journal if (r["iteration"], r["candidate"]) == (shape["iteration"], shape["candidate"]))
    trial = rec["trials"][1]
    video = tmp_path / "trial.mp4"
    proc = replay(run, f"candidate=it{rec['iteration']}_c{rec['candidate']}", f"seed={trial['seed']}", f"video={video}")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    last = json.loads(proc.stdout.strip().splitlines()[-1])
    assert last == {"candidate": f"it{rec['iteration']}_c{rec['candidate']}", "seed": trial["seed"],
                    "outcome": trial["mode"], "journal_outcome": trial["mode"], "match": True}
    recorded = json.loads((run / "replays.jsonl").read_text().splitlines()[-1])
    assert f"recorded in {run / 'replays.jsonl'}" in proc.stdout  # the file it writes is named (issue 40)
    import imageio.v2 as imageio

    reader = imageio.get_reader(str(video))
    assert reader.count_frames() == recorded["frames"] > 10
    assert 0 < video.stat().st_size <= 2_000_000
    proc = replay(run, "candidate=nominal", f"seed={journal[0]['trials'][0]['seed']}")
    assert proc.returncode == 0 and json.loads(proc.stdout.strip().splitlines()[-1])["match"] is True
