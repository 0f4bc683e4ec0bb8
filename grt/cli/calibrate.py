"""``grt-calibrate`` (``python -m grt.calibrate task=NAME policy=NAME trials=32``): a ManiSkill task's nominal
swap against its stock env, seed for seed, and where the two part (:mod:`grt.tasks.maniskill.calibrate`).

Writes into its run folder ``calibration.json`` (the command, the task, the seeds, per run the success rate,
every seed's outcome, the actor's mass and extents; the per-seed agreement and the mass and extents ratios;
``fidelity``: the open-loop replays, the swapped actor's pose divergence per control step), ``fidelity.png``
(the divergence against the step) and the replayed actions (``fidelity_actions_<seed>.npy``, to replay again
with ``fidelity.actions=FILE``), and prints the figures. Without a policy (``~policy``) it compares no
outcomes and replays GRT's scripted push. A task that is no ManiSkill task, or a calibration that cannot run
(the stock env does not build, the policy fails on the stock actor, the swap does not build), is refused in
one line (exit code 2, nothing written).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import hydra
import numpy as np
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

SOURCES = ("auto", "policy", "push")


def _check_settings(cfg: DictConfig, has_policy: bool) -> None:
    """The numbers and the fidelity source, before any simulation (one line each)."""
    for key, low, what in (("trials", 1, "episodes, each run with the stock actor and with the nominal swap"),
                           ("max_hull_vertices", 4, "vertices of a convex part at most"),
                           ("fidelity.episodes", 0, "episodes replayed open-loop on the stock actor and the swap")):
        value = cfg.get("fidelity", {}).get("episodes") if key.startswith("fidelity.") else cfg.get(key)
        if not at_least(low).check(value):
            raise TaskInputError(f"{key}={value}: give {at_least(low).accepts} ({what})")
    for key in ("seed", "fidelity.seed"):
        value = cfg.get("fidelity", {}).get("seed") if key.startswith("fidelity.") else cfg.get("seed")
        if (value is not None or key == "seed") and not at_least(0).check(value):
            raise TaskInputError(f"{key}={value}: give {at_least(0).accepts} (the episode seeds are "
                                 "grt.redteam.episode_seeds(seed, trials), as a run's)")
    source = str(cfg.fidelity.actions)
    if source == "policy" and not has_policy:
        raise TaskInputError("fidelity.actions=policy replays the policy's episode, and no policy is given (~policy): "
                             "give policy=NAME, or fidelity.actions=push or a .npy file of recorded actions")


def _action_file(path: str, kwargs: dict) -> np.ndarray:
    """A recorded action file ``(T, A)``, checked against the env's action space (one line on any problem)."""
    from grt.tasks.maniskill.session import ManiSkillSession

    file = Path(path).expanduser()
    try:
        actions = np.load(file, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise TaskInputError(f"fidelity.actions={path}: not a readable .npy file of actions ({err}); give auto, "
                             "policy, push or a file written by np.save of a (T, A) array") from None
    size = ManiSkillSession.action_size(**kwargs)
    actions = actions.reshape(len(actions), -1) if actions.ndim == 3 and actions.shape[1] == 1 else actions
    if actions.ndim != 2 or actions.shape[1] != size or len(actions) == 0:
        raise TaskInputError(f"fidelity.actions={path}: actions of shape {actions.shape}, but the task's env takes "
                             f"(T, {size}) in control mode {kwargs.get('control_mode')}")
    if not np.isfinite(actions).all():
        raise TaskInputError(f"fidelity.actions={path}: holds NaN or infinite actions")
    return actions.astype(np.float32)


def _plan(cfg: DictConfig, task: dict, has_policy: bool, seeds: list[int]) -> dict | None:
    """The fidelity replays: ``{"source", "seeds", "actions"}``, or ``None`` (``fidelity.episodes=0``)."""
    source, count = str(cfg.fidelity.actions), int(cfg.fidelity.episodes)
    first = int(cfg.fidelity.seed) if cfg.fidelity.get("seed") is not None else seeds[0]
    kwargs = {k: v for k, v in task["session"].items() if k != "_target_"}
    if source not in SOURCES:
        return {"source": "file", "file": source, "seeds": [first], "actions": _action_file(source, kwargs)}
    if count == 0:
        return None
    if source == "auto":
        source = "policy" if has_policy else "push"
    if source == "push":
        from grt.tasks.maniskill.probe import check_control_mode

        check_control_mode(kwargs.get("control_mode"))
    picked = episode_seeds(first, count) if cfg.fidelity.get("seed") is not None else seeds[:count]
    if len(picked) < count:
        picked = episode_seeds(first, count)
    return {"source": source, "seeds": [int(s) for s in picked], "actions": None}


def calibrate_task(cfg: DictConfig, out_dir: Path) -> dict:
    """Calibrate ``cfg.task`` with ``cfg.policy`` on ``cfg.trials`` seeds; returns ``calibration.json``'s record."""
    from grt.tasks.maniskill.calibrate import CalibrationError
    from grt.tasks.maniskill.make import EnvBuildError
    from grt.tasks.maniskill.session import ManiSkillSession

    task = plain(cfg.task)
    policy = plain(cfg.policy) if cfg.get("policy") is not None else None
    _check_settings(cfg, policy is not None)
    if not issubclass(session_class(task), ManiSkillSession):
        raise TaskInputError(f"task={cfg.task.name} is not a ManiSkill task (its session is "
                             f"{task['session']['_target_']}): calibration compares a swapped actor with the stock one")
    check_fit(task, policy)  # no Vulkan, a policy of another kind: before the env is built
    try:
        mesh = load_mesh(task_object(cfg.task, cfg.object, cfg.paths.cache_dir), settings=MeshSettings.from_config(cfg.mesh))
        preflight(task, policy, mesh)
    except EnvBuildError as err:
        raise CalibrationError(f"calibration cannot run: the stock env fails to build: {err}") from None
    parts = make_collision("fast", mesh, None, f"{cfg.paths.cache_dir}/coacd", int(cfg.max_hull_vertices)).parts(mesh)
    seeds = episode_seeds(int(cfg.seed), int(cfg.trials))
    plan = _plan(cfg, task, policy is not None, seeds)
    if policy is None and plan is None:
        raise TaskInputError("no policy (~policy) and fidelity.episodes=0: nothing to calibrate; give policy=NAME, or "
                             "fidelity.episodes >= 1 for the open-loop replays")
    args = (task, policy, mesh.vertices, mesh.faces, parts, seeds if policy is not None else [], plan)
    folders = worker_path(policy)  # a policy with a Python of its own runs in a process started with it
    result = run_in_worker(folders, _calibrate_session, *args) if folders else _calibrate_session(*args)
    record = {"command": " ".join(["python -m grt.calibrate", *sys.argv[1:]]), "task": cfg.task.name,
              "env_id": task.get("env_id"), "actor": task["session"].get("actor"), "object": str(cfg.object),
              "policy": policy, "parts": len(parts), "hull_vertices": [len(p) for p in parts], **result}
    return _save(record, out_dir)


def _save(record: dict, out_dir: Path) -> dict:
    """Write ``calibration.json``, the replayed actions and ``fidelity.png``; returns the record with ``saved``."""
    from grt.fileio import write_text_atomic
    from grt.report.plots import plot_divergence

    out_dir.mkdir(parents=True, exist_ok=True)
    fidelity = record.get("fidelity")
    if fidelity is not None:
        for episode, actions in zip(fidelity["episodes"], fidelity.pop("actions"), strict=True):
            name = f"fidelity_actions_{episode['seed']}.npy"
            np.save(out_dir / name, actions)
            episode["actions_file"] = name
        plot_divergence(fidelity["episodes"], out_dir / "fidelity.png", title=f"{record['task']}: nominal swap vs stock")
    write_text_atomic(out_dir / "calibration.json", json.dumps(record, indent=1))
    record["saved"] = str(out_dir / "calibration.json")
    return record


def _calibrate_session(task: dict, policy: dict | None, vertices, faces, parts, seeds: list[int],
                       plan: dict | None) -> dict:
    """Build the task's session with the policy, calibrate it, replay the fidelity episodes (here or a worker)."""
    import trimesh

    from grt.evaluators.pool import build_session
    from grt.tasks.maniskill.calibrate import CalibrationError, calibrate, fidelity
    from grt.tasks.maniskill.make import EnvBuildError

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    try:
        session = build_session(task, policy) if policy is not None else _bare_session(task)
    except EnvBuildError as err:
        raise CalibrationError(f"calibration cannot run: the stock env fails to build: {err}") from None
    out = {}
    try:
        episodes = len(plan["seeds"]) if plan else 0
        with progress(2 * len(seeds) + episodes, "calibrate (stock, swap, replays)", "episode") as bar:
            if seeds:
                out = calibrate(session, mesh, parts, seeds, on_trial=lambda: bar.update(1))
            if plan:
                out["fidelity"] = fidelity(session, mesh, parts, plan["source"], plan["seeds"], plan["actions"],
                                           on_episode=lambda: bar.update(1))
                if plan.get("file"):
                    out["fidelity"]["file"] = plan["file"]
        return out
    finally:
        session.close()


def _bare_session(task: dict):
    """The task's session with no policy (the policy-free fidelity check)."""
    from grt.tasks.maniskill.session import ManiSkillSession

    return ManiSkillSession(policy=None, **{k: v for k, v in task["session"].items() if k != "_target_"})


def figures(r: dict) -> str:
    """The printed summary of a calibration record."""
    lines = [f"task          {r['task']} ({r['env_id']}, actor {r['actor']}), "
             + (f"{len(r['seeds'])} seeds" if r.get("policy") else "no policy: outcomes not compared")]
    if "stock" in r:
        s, w = r["stock"], r["swap"]
        lines += [f"success       stock {s['success_rate']:.3f}   nominal swap {w['success_rate']:.3f}",
                  f"agreement     {r['agreement']:.3f} of the seeds end in the same outcome",
                  f"mass          stock {s['mass_kg'] * 1000:.2f} g   swap {w['mass_kg'] * 1000:.2f} g   "
                  f"(ratio {r['mass_ratio']:.4f})",
                  f"extents       stock {[round(e * 1000, 2) for e in s['extents_m']]} mm   swap "
                  f"{[round(e * 1000, 2) for e in w['extents_m']]} mm"]
    f = r.get("fidelity")
    if f:
        for e in f["episodes"]:
            onset = e["swap"]["onset_step"]
            lines.append(f"open loop     seed {e['seed']} ({f['source']}, {e['steps']} steps): swap parts by up to "
                         f"{e['swap']['max_mm']:.1f} mm / {e['swap']['max_deg']:.1f} deg"
                         + (f", from step {onset}" if onset is not None else ", never by 1 mm or 1 deg")
                         + f"; a 0.1 mm nudge of the stock actor: {e['nudge']['max_mm']:.1f} mm / "
                         f"{e['nudge']['max_deg']:.1f} deg")
    lines.append(f"saved         {r['saved']}")
    return "\n".join(lines)


@hydra.main(config_path=CONF_DIR, config_name="calibrate", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns the per-seed agreement (NaN without a policy)."""
    with exit_on_user_error():
        record = calibrate_task(cfg, Path(HydraConfig.get().runtime.output_dir))
    print(figures(record))
    return float(record.get("agreement", float("nan")))


def cli() -> None:
    """``grt-calibrate``: a mistake in the command line or the config is one ``error:`` line, exit code 2."""
    run_cli(main)
