"""Sweeps through Hydra's submitit launcher: each job pickled to its own process, as on a SLURM cluster.

``hydra/launcher=submitit_local`` runs the same code path as ``hydra/launcher=slurm`` (the job's pickle, its
folder, submitit's logs), only the jobs start here instead of through sbatch; SLURM itself is not installed
on this machine, so its part is checked up to the sbatch script submitit writes (docs/cluster.md).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.utils import instantiate
from submitit.slurm.slurm import SlurmExecutor, _convert_mem, _make_sbatch_string

from grt.cli.launchers import slurm_here
from tests.runner._toy_run import TOY
from tests.runner.conftest import CONF

ROOT = Path(__file__).resolve().parents[2]


def _cli(*args: str, env: dict | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "WANDB_MODE": "disabled", **(env or {})}
    return subprocess.run([sys.executable, "-m", "grt.run", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


@pytest.mark.sim
@pytest.mark.slow
def test_a_submitit_sweep_runs_each_job_in_its_own_process_and_run_folder(tmp_path):
    # the sweep folder's name has a timestamp down to the microsecond: each job, composed again in its own
    # process, must land in the folder the sweep made (Hydra hands the jobs its resolved `now`)
    res = _cli("-m", "hydra/launcher=submitit_local", "task=insertion", "policy=insertion_state", "budget=smoke",
               "budget.seed=0,1", f"hydra.sweep.dir={tmp_path}/sweep_${{now:%H-%M-%S-%f}}")
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    (sweep,) = tmp_path.iterdir()
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert [p.name for p in jobs] == ["0_insertion_state_heuristic-topdm", "1_insertion_state_heuristic-topdm"]
    for seed, job in enumerate(jobs):
        summary = json.loads((job / "summary.json").read_text())
        assert summary["evaluations"] == 7 and len(_lines(job / "journal.jsonl")) == 7
        assert summary["evaluator"]["backend"] == "pool" and not (job / "error.txt").exists()
        assert f"budget.seed={seed}" in (job / "run_config.yaml").read_text()
    # submitit's record: one folder per job with its pickled call, its result and its logs
    logs = sorted((sweep / ".submitit").glob("*/*_0_log.out"))  # the job's stdout (and .err, its stderr)
    assert len(logs) == 2 and all("Job completed successfully" in p.read_text() for p in logs)
    assert all("run folder: " in p.read_text() for p in logs)  # GRT's own summary lines are there too
    assert len(list((sweep / ".submitit").glob("*/*_result.pkl"))) == 2
    report = subprocess.run([sys.executable, "-m", "grt.report", str(sweep)], cwd=ROOT, capture_output=True,
                            text=True, timeout=120)
    assert report.returncode == 0 and "Final Drop" in report.stdout, report.stdout + report.stderr


def test_a_job_that_dies_is_one_line_and_the_same_sweep_again_goes_on_from_its_journal(tmp_path):
    # Ctrl-C inside the job (the toy evaluator's GRT_TEST_INTERRUPT_AT) ends its process without a result, as
    # a kill or a time limit would; submitted again (a SLURM requeue runs the same pickled job), the job goes
    # on from its journal in its own folder
    args = ["-m", "hydra/launcher=submitit_local", "budget=smoke", "selector.k=3", "budget.trials=2", *TOY,
            f"hydra.sweep.dir={tmp_path}"]
    res = _cli(*args, env={"GRT_TEST_INTERRUPT_AT": "3"})
    job = tmp_path / "0_antipodal_heuristic-topdm"
    (line,) = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr[-3000:]
    assert "a job of the sweep did not finish" in line and "_0_log.err" in line
    assert f"python -m grt.run resume={job}" in line  # the job's own last words: how to continue it
    before = _lines(job / "journal.jsonl")
    assert len(before) == 2 and not (job / "summary.json").exists()
    res = _cli(*args)
    assert res.returncode == 0, res.stderr[-3000:]
    after = _lines(job / "journal.jsonl")
    assert after[:2] == before and len(after) == 7 and (job / "summary.json").exists()
    assert "resuming" in (job / "run.log").read_text()


def test_a_sweep_run_again_is_judged_by_its_own_jobs_not_an_earlier_sweeps_leftovers(tmp_path):
    # an earlier sweep's unfinished job under a job name GRT no longer makes (before the policy was in it): the
    # same sweep again runs its job under today's name and succeeds; the leftover is named, not a failure
    old = tmp_path / "0_heuristic-topdm"
    old.mkdir()
    (old / "run_config.yaml").write_text("task: grasp\n")  # a run's record, no summary.json: never finished
    (old / "journal.jsonl").write_text("")
    res = _cli("-m", "budget=smoke", "selector.k=3", "budget.trials=2", *TOY, f"hydra.sweep.dir={tmp_path}")
    assert res.returncode == 0 and "error:" not in res.stderr, res.stderr[-3000:]
    assert (tmp_path / "0_antipodal_heuristic-topdm" / "summary.json").is_file()
    assert ("1 job folder of an earlier sweep here, not run by this one, did not finish: 0_heuristic-topdm"
            in res.stdout)


def _launcher(config_name: str, overrides: list[str]):
    """The launcher Hydra makes for ``python -m grt.<app> -m <overrides>`` (instantiated as Hydra does)."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name, overrides=overrides, return_hydra_config=True)
    return instantiate(cfg.hydra.launcher)


def test_the_slurm_launcher_config_makes_the_sbatch_script_of_the_sweep(tmp_path):
    """``hydra/launcher=slurm`` resolved as Hydra instantiates it, then written by submitit's own sbatch
    writer as its SLURM executor would (parameter names mapped as the launcher maps them)."""
    launcher = _launcher("run", ["hydra/launcher=slurm", "budget=paper", "budget.workers=6",
                                 "hydra.launcher.partition=cpu", "+hydra.launcher.additional_parameters.mail-type=END"])
    assert type(launcher).__name__ == "SlurmLauncher"  # the plugin's (Hydra loads its plugins itself)
    params = launcher.params
    assert params["cpus_per_task"] == 6 and params["mem_gb"] == 8 and params["gpus_per_node"] is None
    assert params["timeout_min"] == 240 and params["max_num_timeout"] == 3 and params["array_parallelism"] == 32
    names = SlurmExecutor._equivalence_dict()  # generic names (timeout_min, mem_gb) to sbatch's (time, mem)
    sbatch = {names.get(k, k): v for k, v in params.items() if k not in ("submitit_folder", "max_num_timeout")}
    sbatch["mem"] = _convert_mem(sbatch["mem"])
    script = _make_sbatch_string(command="python -u -m submitit.core._submit FOLDER", folder=tmp_path / "%j",
                                 map_count=40, **sbatch)
    for line in ("#SBATCH --cpus-per-task=6", "#SBATCH --mem=8GB", "#SBATCH --partition=cpu",
                 "#SBATCH --time=240", "#SBATCH --array=0-39%32", "#SBATCH --signal=USR2@120",
                 "#SBATCH --mail-type=END", f"source {sys.prefix}/bin/activate 2>/dev/null || true",
                 "export PYTHONUNBUFFERED=1"):
        assert line in script.splitlines(), line
    assert "--gpus" not in script  # no GPU asked for, not even 0 (refused on some clusters without GPUs)
    # another app's workers size its jobs too (python -m grt.blueteam -m ... workers=5)
    launcher = _launcher("blueteam", ["hydra/launcher=slurm", "workers=5"])
    assert launcher.params["cpus_per_task"] == 5 and launcher.params["mem_gb"] == 7


@pytest.mark.skipif(slurm_here(), reason="SLURM is installed here: the launcher would submit")
def test_a_slurm_sweep_where_there_is_no_slurm_and_bad_launcher_settings_are_one_line(tmp_path):
    for launcher in ("slurm", "submitit_slurm"):
        res = _cli("-m", f"hydra/launcher={launcher}", "budget=smoke", "budget.seed=0,1",
                   f"hydra.sweep.dir={tmp_path / launcher}")
        assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
        assert res.stderr.strip().splitlines() == [
            f"error: hydra/launcher={launcher} submits the sweep's jobs to SLURM, but this machine has no SLURM (no "
            "srun or sbatch on PATH): run the command on the cluster's login node, or try the sweep here with "
            "hydra/launcher=submitit_local (or leave hydra/launcher out)"]
        assert not (tmp_path / launcher).exists()  # nothing written
    for bad, words in (("hydra.launcher.timeout_min=soon", "timeout_min"), ("hydra.launcher.partion=cpu", "partion")):
        res = _cli("-m", "hydra/launcher=submitit_local", bad, "budget=smoke", f"hydra.sweep.dir={tmp_path / 'bad'}")
        (line,) = res.stderr.strip().splitlines()
        assert res.returncode == 2 and line.startswith("error: ") and words in line, res.stderr
