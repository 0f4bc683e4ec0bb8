"""``grt-calibrate`` (``python -m grt.calibrate task=NAME policy=NAME trials=32``): a ManiSkill task's nominal
swap against its stock env, seed for seed (:mod:`grt.tasks.maniskill.calibrate`).

Writes ``calibration.json`` into its run folder (the command, the task, the seeds, per run the success rate,
every seed's outcome, the actor's mass and extents; the per-seed agreement and the mass and extents ratios)
and prints the figures. A task that is no ManiSkill task is refused in one line (exit code 2).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from grt.cli._common import CONF_DIR, exit_on_user_error, run_cli
from grt.config import at_least, plain
from grt.console import progress
from grt.evaluators.collision import make_collision
from grt.evaluators.worker_env import run_in_worker, worker_path
from grt.geometry.mesh import load_mesh
from grt.geometry.prepare import MeshSettings
from grt.redteam import episode_seeds
from grt.tasks import TaskInputError, check_fit, preflight, session_class, task_object


def calibrate_task(cfg: DictConfig, out_dir: Path) -> dict:
    """Calibrate ``cfg.task`` with ``cfg.policy`` on ``cfg.trials`` seeds; returns ``calibration.json``'s record."""
    from grt.tasks.maniskill.session import ManiSkillSession

    task = plain(cfg.task)
    for key, low, what in (("trials", 1, "episodes, each run with the stock actor and with the nominal swap"),
                           ("max_hull_vertices", 4, "vertices of a convex part at most")):
        if not at_least(low).check(cfg.get(key)):
            raise TaskInputError(f"{key}={cfg.get(key)}: give {at_least(low).accepts} ({what})")
    if not at_least(0).check(cfg.get("seed")):  # as budget.seed: episode_seeds takes no negative seed
        raise TaskInputError(f"seed={cfg.get('seed')}: give {at_least(0).accepts} (the episode seeds are "
                             "grt.redteam.episode_seeds(seed, trials), as a run's)")
    if not issubclass(session_class(task), ManiSkillSession):
        raise TaskInputError(f"task={cfg.task.name} is not a ManiSkill task (its session is "
                             f"{task['session']['_target_']}): calibration compares a swapped actor with the stock one")
    check_fit(task, plain(cfg.policy))  # no Vulkan, a policy of another kind: before the env is built
    mesh = load_mesh(task_object(cfg.task, cfg.object, cfg.paths.cache_dir), settings=MeshSettings.from_config(cfg.mesh))
    preflight(task, plain(cfg.policy), mesh)
    parts = make_collision("fast", mesh, None, f"{cfg.paths.cache_dir}/coacd", int(cfg.max_hull_vertices)).parts(mesh)
    seeds = episode_seeds(int(cfg.seed), int(cfg.trials))
    args = (task, plain(cfg.policy), mesh.vertices, mesh.faces, parts, seeds)
    folders = worker_path(plain(cfg.policy))  # a policy with a Python of its own runs in a process started with it
    result = run_in_worker(folders, _calibrate_session, *args) if folders else _calibrate_session(*args)
    record = {"command": " ".join(["python -m grt.calibrate", *sys.argv[1:]]), "task": cfg.task.name,
              "env_id": task.get("env_id"), "actor": task["session"].get("actor"), "object": str(cfg.object),
              "policy": plain(cfg.policy), "parts": len(parts), **result}
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "calibration.json").write_text(json.dumps(record, indent=1))
    record["saved"] = str(out_dir / "calibration.json")
    return record


def _calibrate_session(task: dict, policy: dict, vertices, faces, parts, seeds: list[int]) -> dict:
    """Build the task's session with the policy and calibrate it (in this process or a worker's)."""
    import trimesh

    from grt.evaluators.pool import build_session
    from grt.tasks.maniskill.calibrate import calibrate

    session = build_session(task, policy)
    try:
        with progress(2 * len(seeds), "calibrate (stock, then swap)", "trial") as bar:
            return calibrate(session, trimesh.Trimesh(vertices, faces, process=False), parts, seeds,
                             on_trial=lambda: bar.update(1))
    finally:
        session.close()


def figures(r: dict) -> str:
    s, w = r["stock"], r["swap"]
    return "\n".join([
        f"task          {r['task']} ({r['env_id']}, actor {r['actor']}), {len(r['seeds'])} seeds",
        f"success       stock {s['success_rate']:.3f}   nominal swap {w['success_rate']:.3f}",
        f"agreement     {r['agreement']:.3f} of the seeds end in the same outcome",
        f"mass          stock {s['mass_kg'] * 1000:.2f} g   swap {w['mass_kg'] * 1000:.2f} g   (ratio {r['mass_ratio']:.4f})",
        f"extents       stock {[round(e * 1000, 2) for e in s['extents_m']]} mm   swap "
        f"{[round(e * 1000, 2) for e in w['extents_m']]} mm",
        f"saved         {r['saved']}"])


@hydra.main(config_path=CONF_DIR, config_name="calibrate", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns the per-seed agreement."""
    with exit_on_user_error():
        record = calibrate_task(cfg, Path(HydraConfig.get().runtime.output_dir))
    print(figures(record))
    return float(record["agreement"])


def cli() -> None:
    """``grt-calibrate``: a mistake in the command line or the config is one ``error:`` line, exit code 2."""
    run_cli(main)
