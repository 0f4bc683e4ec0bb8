"""Run folders of every format load through one migration, resume and report (:mod:`grt.runfolder`).

``tests/data/run_format1_toy`` was written by the release before the format version (commit 94b8157,
``python -m grt.run budget=smoke selector.k=3 optimizer=gaussian`` with the toy evaluator of ``_toy_run``,
stopped by Ctrl-C after S0 and one candidate; absolute paths replaced by neutral ones): format 1.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from grt.blueteam.core import load_run
from grt.config import make_plan
from grt.runfolder.record import (
    FORMAT,
    FORMAT_KEY,
    RUN_CONFIG,
    ResumeError,
    load_run_config,
    migrate,
    save_run_config,
)
from grt.runfolder.resume import SavedRun, resume_overrides
from tests.runner._toy_run import TOY
from tests.runner.conftest import compose_run

ROOT = Path(__file__).resolve().parents[2]
RELEASE = ROOT / "tests" / "data" / "run_format1_toy"
# its overrides (module doc): the toy run's of its release, when the toy session was the base class itself
RELEASE_COMMAND = ["budget=smoke", "selector.k=3", "optimizer=gaussian", "task.session._target_=grt.tasks.base.TaskSession",
                   TOY[1]]


@pytest.fixture
def release_run(tmp_path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(RELEASE, copy)
    return copy


def _old_style(run_dir: Path) -> None:
    """Make the record what a run of an older release wrote: evaluator ``grt.eval.evaluator.SimEvaluator``
    and none of the keys added since (object_scale, mesh, the deformer's settings, budget.confirm_trials,
    task.nominal_floor)."""
    path = run_dir / RUN_CONFIG
    record = OmegaConf.load(path)
    record.config.evaluator._target_ = "grt.eval.evaluator.SimEvaluator"
    record.config.deformer = {}
    for parent, key in (("config", "object_scale"), ("config", "mesh"),
                        ("config.budget", "confirm_trials"), ("config.task", "nominal_floor")):
        OmegaConf.select(record, parent).pop(key)
    path.chmod(0o644)
    path.write_text(OmegaConf.to_yaml(record))


def test_the_release_folder_is_format_1_and_migrates_without_changing_its_values(release_run):
    record = OmegaConf.load(release_run / RUN_CONFIG)
    assert FORMAT_KEY not in record
    cfg = OmegaConf.create(load_run_config(release_run))
    expected = OmegaConf.to_container(record.config)  # nothing was missing but the keys added since, off
    expected["budget"]["tau_rel"], expected["deformer"]["max_volume_change"] = None, None
    expected["budget"].update(racing=False, race_rounds=8, race_alpha=0.05, size_penalty=0.0)
    assert OmegaConf.to_container(cfg) == expected
    saved = SavedRun.load(release_run)
    assert saved.format == 1 and saved.overrides == RELEASE_COMMAND and saved.choices["optimizer"] == "gaussian"


def test_an_old_style_config_naming_grt_eval_is_migrated(release_run):
    _old_style(release_run)
    cfg = OmegaConf.create(load_run_config(release_run))
    assert cfg.evaluator._target_ == "grt.evaluators.sim.SimEvaluator"  # the grt.eval alias package is gone
    assert cfg.object_scale == 1.0 and cfg.mesh == {} and cfg.budget.confirm_trials == 0
    assert dict(cfg.deformer) == {"lam": 1.0, "method": "exact", "radius": 0.35, "validity": False,
                                  "max_volume_change": None}
    assert cfg.task.nominal_floor == 0.25  # what an absent floor meant for a binary task
    run, records = load_run(release_run)  # the blue team reads the same migrated config, as the run's plan
    assert run.config == OmegaConf.to_container(cfg) and run.task == OmegaConf.to_container(cfg.task, resolve=True)
    assert run.run_dir == release_run and len(records) == 2
    with pytest.raises(ResumeError, match=r"deformer.method \(the run's: exact, given: smooth\)"):
        resume_overrides([f"resume={release_run}", "deformer.method=smooth"])


def test_migrate_keeps_interpolations_and_current_configs():
    cfg = compose_run(["budget=smoke"])
    assert migrate(OmegaConf.to_container(cfg), FORMAT) == OmegaConf.to_container(cfg)
    old = OmegaConf.create({"object": "${task.object}", "task": {"object": "mug"},
                            "evaluator": {"_target_": "grt.eval.evaluator.SimEvaluator", "workers": 2}})
    new = OmegaConf.create(migrate(OmegaConf.to_container(old), 1))
    assert OmegaConf.to_container(new)["object"] == "${task.object}" and new.object == "mug"
    assert new.evaluator == {"_target_": "grt.evaluators.sim.SimEvaluator", "workers": 2}
    assert old.evaluator._target_ == "grt.eval.evaluator.SimEvaluator"  # the given config is not changed


def test_a_format_0_folder_is_read_from_hydras_record(release_run):
    (release_run / RUN_CONFIG).chmod(0o644)
    (release_run / RUN_CONFIG).unlink()
    cfg = OmegaConf.create(load_run_config(release_run))
    assert cfg.budget.population == 3 and cfg.object == "mug"
    assert SavedRun.load(release_run).format == 0


def test_a_new_record_carries_the_format(tmp_path):
    cfg = compose_run(["budget=smoke", f"paths.output_dir={tmp_path}"])
    save_run_config(make_plan(cfg))
    record = OmegaConf.load(tmp_path / RUN_CONFIG)
    assert record[FORMAT_KEY] == FORMAT == 2
    assert (tmp_path / RUN_CONFIG).stat().st_mode & 0o222 == 0


def _cli(module: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", module, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env={**os.environ, "WANDB_MODE": "disabled"})


@pytest.mark.parametrize("old_style", [False, True], ids=["release", "grt.eval-era"])
def test_a_folder_of_the_release_resumes_and_reports(release_run, old_style):
    if old_style:  # a run of an older release: the migration fills in what its config lacks
        _old_style(release_run)
        record = OmegaConf.load(release_run / RUN_CONFIG)
        release = OmegaConf.load(RELEASE / RUN_CONFIG).config
        record.config.evaluator._target_ = release.evaluator._target_  # the toy: no simulator here
        # the journal was made with these (the migrated defaults would be another mesh, another deformation)
        record.config.deformer, record.config.mesh = release.deformer, release.mesh
        (release_run / RUN_CONFIG).write_text(OmegaConf.to_yaml(record))
    before = (release_run / RUN_CONFIG).read_bytes()
    res = _cli("grt.run", f"resume={release_run}")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    summary = json.loads((release_run / "summary.json").read_text())
    assert (summary["optimizer"], summary["num_handles"], summary["evaluations"]) == ("gaussian", 3, 7)
    assert (release_run / RUN_CONFIG).read_bytes() == before  # the record of the start is never rewritten
    report = _cli("grt.report", str(release_run))
    assert report.returncode == 0 and "gaussian" in report.stdout, report.stdout + report.stderr
