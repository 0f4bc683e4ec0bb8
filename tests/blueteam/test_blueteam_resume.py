"""``python -m grt.blueteam resume=DIR`` alone continues a study with its own config, ``run=`` included (Hydra's
record of its start, ``DIR/.hydra``, which stays as it was); an override that would change the study is refused
before Hydra starts, naming the key; a folder that is not a study is refused; a folder whose ``.hydra`` a resume
rewrote (before this was so) still resumes, with that record.

These tests read a record written here from the composed config (as Hydra writes it); a real tiny study
killed and resumed with ``resume=DIR`` alone is the end of
``tests/blueteam/test_blueteam.py::test_fine_tune_writes_table3_and_a_loadable_checkpoint_then_resumes``.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf, open_dict

from grt.config import plain
from grt.runfolder.record import ResumeError
from grt.runfolder.resume import STUDY, SavedRun, own_study_config, resume_overrides
from tests.blueteam.conftest import ROOT, _cli
from tests.blueteam.test_blueteam import TINY

RELEASE = ROOT / "tests" / "data" / "run_format1_toy"  # a red-team run's folder


def first(run: Path | str) -> list[str]:
    """A study's command: not the defaults (a resume must keep them)."""
    return [f"run={run}", *TINY, "blueteam.crashshapes=topk", "blueteam.rered.enabled=false"]


def write_record(folder: Path, overrides: list[str]) -> None:
    """``folder/.hydra`` as Hydra writes it for ``python -m grt.blueteam *overrides`` (its three files)."""
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="blueteam", overrides=overrides, return_hydra_config=True)
    choices = OmegaConf.to_container(cfg.hydra.runtime.choices)
    with open_dict(cfg):
        del cfg["hydra"]
    hydra_dir = folder / ".hydra"
    hydra_dir.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(cfg, hydra_dir / "config.yaml")
    OmegaConf.save(OmegaConf.create(overrides), hydra_dir / "overrides.yaml")
    OmegaConf.save(OmegaConf.create({"hydra": {"runtime": {"choices": choices}}}), hydra_dir / "hydra.yaml")


def tree(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(folder.rglob("*"))}


@pytest.fixture
def recorded(tmp_path) -> Path:
    folder = tmp_path / "study"
    write_record(folder, first(tmp_path / "redteam"))
    return folder


def one_error_line(res) -> str:
    assert res.returncode == 2, res.stdout[-2000:] + res.stderr[-3000:]
    assert "Traceback" not in res.stdout + res.stderr, res.stderr[-3000:]
    errors = [line for line in res.stderr.splitlines() if line.strip()]
    assert len(errors) == 1 and errors[0].startswith("error: "), res.stderr[-3000:]
    return errors[0]


@pytest.mark.parametrize("given", [
    [], ["blueteam.crashshapes=topk", "blueteam.seed=0", "blueteam.num_envs=2", "blueteam=default"],  # its own
    ["workers=4"], ["blueteam.iterations=50", "blueteam.val_patience=10"], ["blueteam.rered.enabled=true"],
    ["paths.cache_dir=/tmp/cache"],
    ["evaluator=ray", "evaluator.address=HOST:6379"], ["evaluator.workers=3", "evaluator.trial_timeout=60"],
    ["hydra.verbose=true"], ["hydra/job_logging=disabled"],
])
def test_a_resume_is_the_studys_own_command_plus_what_cannot_change_it(given, recorded, tmp_path):
    resume = f"resume={recorded}"
    kept = ("blueteam.crashshapes", "blueteam.seed", "blueteam.num_envs", "blueteam=")
    free = [g for g in given if not g.startswith(kept)]
    own = [o for o in first(tmp_path / "redteam")
           if o.partition("=")[0] not in {g.partition("=")[0] for g in free}]  # a free one replaces the study's
    assert resume_overrides([*given, resume], STUDY) == [*own, "hydra.output_subdir=.hydra/resume", *free, resume]


@pytest.mark.parametrize(("given", "key", "theirs"), [
    ("run=elsewhere", "run", "<run>"), ("blueteam.crashshapes=top1", "blueteam.crashshapes", "topk"),
    ("blueteam.eval_trials=32", "blueteam.eval_trials", "1"), ("blueteam.seed=1", "blueteam.seed", "0"),
    ("blueteam.val_interval=5", "blueteam.val_interval", "1"), ("blueteam.num_envs=16", "blueteam.num_envs", "2"),
    ("blueteam.nominal_guard=tolerance", "blueteam.nominal_guard", "fisher"),
    ("blueteam.algorithm.learning_rate=0.001", "blueteam.algorithm.learning_rate", "0.0001"),
    ("blueteam.heldout.nearby=0", "blueteam.heldout.nearby", "1"), ("blueteam.confirm.trials=8", "blueteam.confirm.trials", "2"),
    ("evaluator.collision=coacd", "evaluator.collision", "fast"), ("~blueteam.anchor", "blueteam.anchor", ".*"),
    ("paths.output_dir=/tmp/x", "paths.output_dir", ".*"), ("+blueteam.extra=1", "blueteam.extra", "unset"),
])
def test_a_resume_that_changes_the_study_names_the_key(given, key, theirs, recorded, tmp_path):
    theirs = theirs.replace("<run>", str(tmp_path / "redteam"))
    with pytest.raises(ResumeError, match=rf"^resume=\S+: {key} \(the study's: {theirs}, given: .*would change the "
                                          r"study, which keeps its own config \(\.hydra/config\.yaml there\).*"
                                          r"allowed with it: workers, blueteam\.iterations.*start a new study"):
        resume_overrides([f"resume={recorded}", given], STUDY)


def outputs() -> set[str]:
    folder = ROOT / "outputs" / "blueteam"
    return {p.name for p in folder.iterdir()} if folder.is_dir() else set()


def test_a_changing_resume_is_one_line_before_hydra_and_writes_nothing(recorded, tmp_path):
    before, made = tree(tmp_path), outputs()
    line = one_error_line(_cli("grt.blueteam", f"resume={recorded}", "run=elsewhere", "blueteam.iterations=9",
                               "blueteam.seed=3"))
    assert f"run (the study's: {tmp_path / 'redteam'}, given: elsewhere), blueteam.seed (the study's: 0, given: 3) " \
           "would change the study" in line, line
    assert "blueteam.iterations" not in line.split("would change")[0], line  # a free key is no change
    assert tree(tmp_path) == before  # no .hydra/resume, no blueteam.log, no lock file
    assert outputs() == made  # no new study folder either


@pytest.mark.parametrize(("folder", "message"), [
    ("notes", "not a study folder of python -m grt.blueteam"), ("training", "not a study folder"),
    ("gone", "no such folder")])
def test_a_resume_of_a_folder_that_is_not_a_study_is_refused(folder, message, tmp_path):
    target = tmp_path / folder
    if folder == "notes":
        target.mkdir()
        (target / "notes.txt").write_text("mine\n")
    elif folder == "training":  # a grt.train folder: Hydra's record, but of a training
        (target / ".hydra").mkdir(parents=True)
        (target / ".hydra" / "config.yaml").write_text("task: {name: drawer}\ntrain: {iterations: 2}\nresume: null\n")
    with pytest.raises(ResumeError, match=rf"^resume={target}: {message}.*, so nothing to resume\. Give the folder "
                                          r"of an earlier study \(outputs/blueteam/<time>\)"):
        resume_overrides([f"resume={target}"], STUDY)


def test_a_resume_of_a_red_team_run_is_one_line_before_hydra_and_writes_nothing(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(RELEASE, run)
    before, made = tree(tmp_path), outputs()
    line = one_error_line(_cli("grt.blueteam", f"resume={run}"))
    assert line.startswith(f"error: resume={run}: {run} already holds a red-team run (run_config.yaml there)"), line
    assert f"Blue-team that run with run={run} (without resume=)" in line, line
    assert tree(tmp_path) == before and outputs() == made


def test_a_resumes_config_is_the_record_with_the_free_keys_of_its_command(recorded, tmp_path):
    overrides = resume_overrides([f"resume={recorded}", "workers=3", "blueteam.iterations=7",
                                  "paths.cache_dir=/tmp/cache", "evaluator.trial_timeout=60"], STUDY)
    overrides = [o for o in overrides if not o.startswith("hydra.")] + [f"paths.output_dir={recorded}"]  # Hydra's
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        composed = compose(config_name="blueteam", overrides=overrides)
    record = OmegaConf.load(recorded / ".hydra" / "config.yaml")
    with open_dict(record):  # the record's YAML of that day: a key it lacks today's conf must not bring back
        record.blueteam.val_patience = 11
    OmegaConf.save(record, recorded / ".hydra" / "config.yaml")
    own = OmegaConf.create(own_study_config(str(recorded), plain(composed), overrides))
    assert own.run == str(tmp_path / "redteam") and own.resume == str(recorded)
    assert (own.workers, own.blueteam.iterations, own.paths.cache_dir) == (3, 7, "/tmp/cache")
    assert own.blueteam.val_patience == 11 and own.blueteam.crashshapes == "topk"  # the record's, not today's
    assert own.blueteam.rered.enabled is False
    composed.blueteam.iterations = 150  # not given: the record's, whatever today's default
    assert own_study_config(str(recorded), plain(composed),
                            [o for o in overrides if "iterations" not in o])["blueteam"]["iterations"] == 2
    assert (own.evaluator.workers, own.evaluator.trial_timeout, own.evaluator.collision) == (3, 60, "fast")


def test_a_record_a_resume_rewrote_still_resumes(recorded, tmp_path):
    """Before grt.blueteam kept the start's record, a resume (``run=... resume=DIR``) rewrote ``.hydra``."""
    assert SavedRun.study(recorded).started
    write_record(recorded, [*first(tmp_path / "redteam"), "resume=null"])  # a start, though it names resume=
    assert SavedRun.study(recorded).started
    again = [f"run={tmp_path / 'redteam'}", *TINY, "blueteam.val_patience=99", f"resume={recorded}"]
    write_record(recorded, again)
    saved = SavedRun.study(recorded)
    assert not saved.started and saved.overrides == again[:-1]
    assert resume_overrides([f"resume={recorded}"], STUDY) == [*again[:-1], "hydra.output_subdir=.hydra/resume",
                                                               f"resume={recorded}"]


def test_a_resume_with_a_free_key_out_of_range_is_one_line_and_the_study_keeps_its_record(recorded):
    """A free key (``blueteam.iterations``) is checked with the study's settings as the library reads them
    (:class:`grt.blueteam.spec.StudySpec`), before the red-team run is read or anything is trained."""
    start = tree(recorded / ".hydra")
    line = one_error_line(_cli("grt.blueteam", f"resume={recorded}", "blueteam.iterations=0"))
    assert line.startswith("error: blueteam.iterations=0: give an integer >= 1 (nothing was saved in"), line
    assert {k: v for k, v in tree(recorded / ".hydra").items() if not k.startswith("resume")} == start
    assert not (recorded / "metrics.csv").exists() and not (recorded / "scores.json").exists()
