"""``python -m grt.train resume=DIR`` alone continues a training with its own config (Hydra's record of its
start, ``DIR/.hydra``, which stays as it was); an override that would change the training is refused before
Hydra starts, naming the key; a folder without ``last.pt`` says that training starts at iteration 0; a folder
whose ``.hydra`` a resume rewrote (before this was so) still resumes.

The fast tests read a record written here from the composed config (as Hydra writes it); the slow ones train
a really tiny drawer policy (not the default task) for two iterations and resume it (~9 s each).
"""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf, open_dict

from grt.runfolder.record import ResumeError
from grt.runfolder.resume import TRAINING, SavedRun, resume_overrides
from tests.cli.test_train_cli import ROOT, grt_train, one_error_line

# Not the defaults (task=insertion train=insertion_state): a resume must keep them. Tiny: 2 envs in this
# process, 4 steps an iteration, no warm start, validation or evaluation.
FIRST = ["task=drawer", "train=drawer_state", "train.num_envs=2", "train.workers=0", "train.iterations=2",
         "train.num_steps_per_env=4", "train.max_steps=8", "train.bc=null", "train.validation=null",
         "train.save_interval=1", "eval_trials=0"]
RELEASE = ROOT / "tests" / "data" / "run_format1_toy"  # a red-team run's folder


def write_record(folder: Path, overrides: list[str]) -> None:
    """``folder/.hydra`` as Hydra writes it for ``python -m grt.train *overrides`` (its three files)."""
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="train_policy", overrides=overrides, return_hydra_config=True)
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
    folder = tmp_path / "training"
    write_record(folder, FIRST)
    return folder


@pytest.mark.parametrize("given", [
    [], ["task=drawer", "train.seed=0", "train.num_envs=2"],  # the training's own values
    ["train.iterations=50"], ["train.save_interval=5", "train.workers=1"], ["eval_trials=32"],
    [f"train.export={ROOT}/mine.pt", "train.overwrite_shipped=true"], ["logger=wandb", "logger.mode=offline"],
    ["paths.cache_dir=/tmp/cache"], ["hydra.verbose=true"], ["hydra/job_logging=disabled"],
])
def test_a_resume_is_the_trainings_own_command_plus_what_cannot_change_it(given, recorded):
    resume = f"resume={recorded}"
    free = [g for g in given if not g.startswith(("task=", "train.seed", "train.num_envs"))]
    own = [o for o in FIRST if o.partition("=")[0] not in {g.partition("=")[0] for g in free}]  # a free one replaces
    assert resume_overrides([*given, resume], TRAINING) == [*own, "hydra.output_subdir=.hydra/resume", *free, resume]


@pytest.mark.parametrize(("given", "key", "theirs"), [
    ("task=insertion", "task", "drawer"), ("train=insertion_state", "train", "drawer_state"),
    ("train.seed=1", "train.seed", "0"), ("train.num_envs=16", "train.num_envs", "2"),
    ("train.algorithm.learning_rate=0.001", "train.algorithm.learning_rate", "0.0001"),
    ("train.validation.trials=4", "train.validation.trials", "unset"), ("object=drawer_pull", "object", "drawer_handle"),
    ("init_checkpoint=x.pt", "init_checkpoint", "None"), ("~train.bc", "train.bc", "None"),
    ("paths.output_dir=/tmp/x", "paths.output_dir", "unset"),
])
def test_a_resume_that_changes_the_training_names_the_key(given, key, theirs, recorded):
    with pytest.raises(ResumeError, match=rf"^resume=\S+: {key} \(the training's: {theirs}, given: .*would change the "
                                          r"training.*allowed with it: train\.iterations.*start a new training"):
        resume_overrides([f"resume={recorded}", given], TRAINING)


def test_a_changing_resume_is_one_line_before_hydra_and_writes_nothing(recorded, tmp_path):
    before = tree(tmp_path)
    line = one_error_line(grt_train(f"resume={recorded}", "task=insertion", "train.iterations=9", cwd=tmp_path))
    assert "task (the training's: drawer, given: insertion) would change the training" in line, line
    assert "train.iterations" not in line.split("would change")[0], line  # a free key is no change
    assert tree(tmp_path) == before  # no outputs/, no .hydra/resume, no train.log


@pytest.mark.parametrize(("folder", "message"), [
    ("notes", "not a training folder"), ("run", "not a training folder"), ("gone", "no such folder")])
def test_a_resume_of_a_folder_that_is_not_a_training_is_refused(folder, message, tmp_path):
    target = tmp_path / folder
    if folder == "notes":
        target.mkdir()
        (target / "notes.txt").write_text("mine\n")
    elif folder == "run":
        shutil.copytree(RELEASE, target)
    with pytest.raises(ResumeError, match=rf"^resume={target}: {message}.*, so nothing to resume"):
        resume_overrides([f"resume={target}"], TRAINING)


def test_a_record_a_resume_rewrote_still_resumes(recorded):
    """Before grt.train kept the start's record, ``resume=DIR`` alone rewrote ``.hydra`` with the defaults."""
    assert SavedRun.training(recorded).started
    write_record(recorded, [*FIRST, "resume=null"])  # a start, though it names resume=
    assert SavedRun.training(recorded).started
    write_record(recorded, [f"resume={recorded}"])
    saved = SavedRun.training(recorded)
    assert not saved.started and saved.overrides == []
    assert resume_overrides([f"resume={recorded}"], TRAINING) == ["hydra.output_subdir=.hydra/resume",
                                                                  f"resume={recorded}"]


# --------------------------------------------------------------------------- real (tiny) trainings

@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A drawer training of two iterations, ``last.pt`` saved after each."""
    folder = tmp_path_factory.mktemp("train") / "drawer"
    res = grt_train(*FIRST, f"hydra.run.dir={folder}", cwd=folder.parent)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return folder


@pytest.fixture
def training(trained, tmp_path) -> Path:
    copy = tmp_path / "drawer"
    shutil.copytree(trained, copy)
    return copy


def metrics(folder: Path) -> list[int]:
    with (folder / "metrics.csv").open() as f:
        return [int(row["iteration"]) for row in csv.DictReader(f)]


def hydra_record(folder: Path) -> dict[str, bytes]:
    return {name: (folder / ".hydra" / name).read_bytes() for name in ("config.yaml", "overrides.yaml", "hydra.yaml")}


@pytest.mark.slow
def test_resume_with_a_free_override_goes_on_from_last_pt_with_the_trainings_own_task(training):
    start = hydra_record(training)
    # eval_trials=1 with the training's train.workers=0 (its envs in this process): the final evaluation
    # still gets a worker process (it once ended in "workers must be >= 1")
    res = grt_train(f"resume={training}", "train.iterations=3", "eval_trials=1", cwd=training.parent)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert f"resuming {training} at iteration 2" in (training / "train.log").read_text()
    assert metrics(training) == [0, 1, 2] and "trained 3 iterations" in res.stdout
    assert len(json.loads((training / "evaluation.json").read_text())["trials"]) == 1
    assert hydra_record(training) == start  # the record of the start, byte for byte
    composed = OmegaConf.load(training / ".hydra" / "resume" / "config.yaml")
    assert (composed.task.name, composed.train.name, composed.train.iterations) == ("drawer", "drawer_state", 3)


@pytest.mark.slow
def test_resume_alone_of_a_folder_without_last_pt_says_it_starts_at_iteration_0(training):
    start = hydra_record(training)
    (training / "last.pt").unlink()
    res = grt_train(f"resume={training}", cwd=training.parent)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    note = f"resume={training}: no last.pt there"
    assert [line for line in res.stdout.splitlines() if note in line][0].endswith(
        "nothing was saved yet, so training starts at iteration 0"), res.stdout[-3000:]
    assert note in (training / "train.log").read_text()
    assert metrics(training) == [0, 1] and (training / "last.pt").is_file()
    assert hydra_record(training) == start
    composed = OmegaConf.load(training / ".hydra" / "resume" / "config.yaml")
    assert (composed.task.name, composed.train.name, composed.train.num_envs) == ("drawer", "drawer_state", 2)


@pytest.mark.slow
def test_a_folder_whose_record_an_old_resume_rewrote_resumes_as_its_last_pt_was_trained(training):
    """The worst such record: an old ``resume=DIR`` alone composed the defaults (insertion), then failed to
    load the drawer's ``last.pt``; the resume trains the drawer, as ``last.pt`` was."""
    write_record(training, [f"resume={training}"])
    res = grt_train(f"resume={training}", "train.iterations=3", "eval_trials=0", cwd=training.parent)  # 32 there
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    log = (training / "train.log").read_text()
    assert "is the record of an earlier resume" in log and "(task drawer, train drawer_state" in log, log
    assert f"resuming {training} at iteration 2" in log and metrics(training) == [0, 1, 2]


def test_a_new_command_in_a_training_folder_with_other_settings_is_refused_and_changes_nothing(training):
    """Without ``resume=``, ``hydra.run.dir`` of a training continues it in place only with its own settings
    (a requeued job's same command; the free keys may differ): before, another task's or warm start's
    settings went on from its last.pt and Hydra's record of them replaced the record of the start."""
    before = tree(training)
    other = [o for o in FIRST if not o.startswith("train.num_envs=")] + ["train.num_envs=4"]
    line = one_error_line(grt_train(*other, f"hydra.run.dir={training}", cwd=training.parent))
    assert f"hydra.run.dir={training} holds a training started with other settings: train.num_envs (the " \
           "training's: 2, this command's: 4)" in line, line
    assert f"python -m grt.train resume={training}" in line, line
    assert tree(training) == before  # not a byte: Hydra's record included
    same = [o for o in FIRST if not o.startswith("train.iterations=")] + ["train.iterations=3"]  # a free key
    res = grt_train(*same, f"hydra.run.dir={training}", cwd=training.parent)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert metrics(training) == [0, 1, 2]  # went on from last.pt


@pytest.mark.slow
def test_a_finished_training_resumed_changes_none_of_its_files_and_a_damaged_last_pt_is_one_line(training):
    """``resume=`` of a finished training said "nothing to train" yet rewrote ``train.json`` and the metrics
    inside ``policy.pt``; a ``last.pt`` cut short was an 89-line traceback."""
    kept = ("train.json", "policy.pt", "last.pt", "metrics.csv", "curve.png")
    before = {name: (training / name).read_bytes() for name in kept}
    res = grt_train(f"resume={training}", cwd=training.parent)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert f"nothing to train: {training} already trained 2 iterations (train.iterations=2)" in res.stdout, res.stdout
    assert {name: (training / name).read_bytes() for name in kept} == before
    last = training / "last.pt"
    last.write_bytes(before["last.pt"][: len(before["last.pt"]) // 2])
    line = one_error_line(grt_train(f"resume={training}", "train.iterations=3", cwd=training.parent))
    assert line.startswith(f"error: {last} cannot be read (") and "restore it, or remove it" in line, line
    assert (training / "train.json").read_bytes() == before["train.json"]
