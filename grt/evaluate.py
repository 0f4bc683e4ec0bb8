"""Score a policy on one object as it is: ``python -m grt.evaluate object=NAME|PATH budget.trials=N``.

The object is scored on the same episode seeds a red-team run with the same ``budget.seed`` uses, so
this reproduces a run's nominal score S0 (or re-scores a CrashShape file). The run folder gets
``evaluation.json`` (every trial); the console gets the figures and, as its last line, one JSON
object: ``success_rate, score, ci95, trials, outcomes, wall_s, trials_per_s, object, mesh_hash``.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import asdict
from pathlib import Path

import hydra
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

import grt.config  # noqa: F401 - registers the config schemas and resolvers
from grt.geometry.mesh import load_mesh, mesh_hash
from grt.redteam import episode_seeds

log = logging.getLogger(__name__)


def evaluate(cfg: DictConfig, output_dir: str | Path) -> dict:
    """Evaluate ``cfg.object`` with ``cfg.budget.trials`` trials; returns the summary (see module doc).

    Raises:
        grt.objects.UnknownObjectError: neither a built-in object nor an existing file.
        MeshError: an unreadable or unusable mesh file.
    """
    from grt.tasks import preflight

    mesh = load_mesh(cfg.object)
    preflight(_plain(cfg.task), instantiate(cfg.policy), mesh)
    seeds = episode_seeds(cfg.budget.seed, cfg.budget.trials)
    output_dir = Path(output_dir)
    render_dir = str(output_dir / "renders") if cfg.get("render", False) else None
    make = instantiate(cfg.evaluator)
    start = time.perf_counter()
    with make(task=_plain(cfg.task), policy=_plain(cfg.policy), nominal=mesh, render_dir=render_dir) as ev:
        result = ev.evaluate([mesh], seeds)[0]
        collision_s = ev.collision_s
    wall = time.perf_counter() - start
    summary = {**result.summary(), "object": str(cfg.object), "mesh_hash": mesh_hash(mesh.vertices, mesh.faces),
               "wall_s": round(wall, 3), "worker_s": round(result.wall_s, 3),
               "trials_per_s": round(len(seeds) / wall, 4), "collision_s": round(collision_s, 4)}
    output_dir.mkdir(parents=True, exist_ok=True)
    record = {**summary, "seeds": seeds, "trials": [asdict(t) for t in result.trials]}
    (output_dir / "evaluation.json").write_text(json.dumps(record, indent=1, default=str))
    if render_dir and not any(Path(render_dir).glob("*.png")):
        log.warning("render=true, but the task session wrote no pictures (it has no render(path))")
    return summary


def _plain(node) -> dict:
    return OmegaConf.to_container(node, resolve=True)


def _print_figures(summary: dict) -> None:
    low, high = summary["ci95"]
    print(f"object        {summary['object']}  (mesh {summary['mesh_hash']})")
    print(f"success rate  {summary['success_rate']:.3f}  95% CI [{low:.3f}, {high:.3f}]  "
          f"over {summary['trials']} trials")
    print("outcomes      " + ", ".join(f"{k}: {v}" for k, v in sorted(summary["outcomes"].items())))
    print(f"wall          {summary['wall_s']:.1f} s  ({summary['trials_per_s']:.3f} trials/s, "
          f"worker time {summary['worker_s']:.1f} s, collision {summary['collision_s'] * 1e3:.0f} ms)")


@hydra.main(config_path="../conf", config_name="evaluate", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns the success rate."""
    from hydra.core.hydra_config import HydraConfig

    from grt.errors import exit_on_user_error

    with exit_on_user_error():
        summary = evaluate(cfg, HydraConfig.get().runtime.output_dir)
    _print_figures(summary)
    print(json.dumps(summary))
    return float(summary["success_rate"])


if __name__ == "__main__":
    main()
