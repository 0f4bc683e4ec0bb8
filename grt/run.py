"""``python -m grt.run``: red-team a policy on a task and object; Hydra entry point.

Examples::

    python -m grt.run                                   # grasp task, default object, budget=quick
    python -m grt.run object=bottle selector=all optimizer=cma_es budget=paper
    python -m grt.run -m selector=heuristic,all optimizer=topdm,gaussian budget=smoke
    python -m grt.run resume=outputs/grasp/mug/heuristic-topdm/2026-11-23_01-00-00

``main`` resolves the config once and calls :func:`run`, a plain function tests import; it returns
the run's Final Drop so Hydra sweepers can optimize it.
"""

from __future__ import annotations

import logging
import math
import time
import traceback
from pathlib import Path

import hydra
import numpy as np
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from tqdm.auto import tqdm

import grt.config  # noqa: F401  (registers schemas and resolvers before composition)
from grt.errors import find_user_error
from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import load_mesh
from grt.journal import Journal, JournalError
from grt.outputs import print_summary, write_outputs
from grt.redteam import RedTeamLoop, episode_seeds
from grt.scores import ScoreSpec
from grt.selectors.base import HandleSet
from grt.tasks import preflight

log = logging.getLogger("grt.run")


def run(cfg: DictConfig) -> dict:
    """Run (or resume) one red-team run; returns its summary (also written to ``summary.json``)."""
    run_dir = Path(cfg.resume or cfg.paths.output_dir)
    if cfg.resume and not (run_dir / "journal.jsonl").exists():
        raise JournalError(f"resume={cfg.resume}: no journal.jsonl there, so nothing to resume. Give the "
                           "folder of an earlier run (outputs/<task>/<object>/<selector>-<optimizer>/<time>).")
    score = ScoreSpec.from_task(cfg.task)  # a bad task.ci fails here, before any simulation
    run_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    mesh = load_mesh(cfg.object)
    preflight(_plain(cfg.task), instantiate(cfg.policy), mesh)  # wrong plug/checkpoint: refused before any file
    handle_set = _select_handles(cfg, mesh, run_dir)
    deformer = ShapeDeformer(mesh, handle_set.handles, handle_set.anchors, lam=cfg.deformer.lam,
                             method=cfg.deformer.method)
    optimizer = instantiate(cfg.optimizer)(num_handles=len(handle_set.handles))
    seeds = episode_seeds(cfg.budget.seed, cfg.budget.trials)
    journal = Journal(run_dir / "journal.jsonl")
    if journal.recovered_truncated_line:
        log.warning("journal: ignored a truncated last line (an interrupted write)")
    if len(journal):
        log.info("resuming %s: %d candidates already in the journal", run_dir, len(journal))
    logger = instantiate(cfg.logger)
    evaluator = instantiate(cfg.evaluator)(task=_plain(cfg.task), policy=_plain(cfg.policy), nominal=mesh,
                                           progress=False)  # the red-team bar shows progress
    total = 1 + cfg.budget.population * cfg.budget.iterations
    bar = tqdm(total=total, desc="red-team", unit="cand", initial=len(journal), dynamic_ncols=True)
    try:
        logger.start(run_dir, name=run_dir.name, config=_plain(cfg))
        loop = RedTeamLoop(
            deformer, optimizer, evaluator, journal, seeds, cfg.budget.iterations, tau=cfg.budget.tau,
            complexity=_entropy,
            on_candidate=lambda rec: _progress(bar, rec, score),
            on_iteration=lambda t, scores: logger.log_iteration(t, {"best_score": optimizer.best_score,
                                                                    "mean_score": float(np.mean(scores))}),
            ci=score.ci)
        result = loop.run()
        bar.close()
        summary = write_outputs(cfg, run_dir, result, deformer, handle_set, evaluator,
                                wall_s=time.perf_counter() - start)
        logger.log_summary(summary)
        logger.log_images({"curve": run_dir / "curve.png", "shapes": run_dir / "shapes.png"})
    finally:
        bar.close()
        evaluator.close()
        logger.finish()
    print_summary(summary, run_dir)
    return summary


def _select_handles(cfg: DictConfig, mesh, run_dir: Path) -> HandleSet:
    """Handles and anchors: from the run folder when resuming, else from the configured selector."""
    path = run_dir / "handles.json"
    if path.exists():
        return HandleSet.from_json(path.read_text())
    selector = instantiate(cfg.selector)
    handle_set = selector.select(mesh, cfg.task.description)
    path.write_text(handle_set.to_json())
    return handle_set


def _entropy(mesh) -> float:
    from grt.geometry.complexity import angular_deficit_entropy

    return angular_deficit_entropy(mesh)


def _progress(bar: tqdm, rec: dict, score: ScoreSpec) -> None:
    bar.update(1)
    bar.set_postfix(it=rec["iteration"], score=score.fmt(rec["score"], unit=True))


def _plain(node) -> dict:
    return OmegaConf.to_container(node, resolve=True)


@hydra.main(config_path="../conf", config_name="run", version_base="1.3")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns Final Drop (NaN for a failed job of a sweep, which goes on)."""
    try:
        summary = run(cfg)
    except Exception as exc:
        if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
            out = Path(cfg.resume or cfg.paths.output_dir)
            out.mkdir(parents=True, exist_ok=True)
            (out / "error.txt").write_text(traceback.format_exc())
            log.error("job failed (%s: %s); details in %s; the sweep goes on",
                      type(exc).__name__, exc, out / "error.txt")
            return math.nan
        found = find_user_error(exc)
        if found is not None:
            log.error("%s: %s", type(found).__name__, found)
            raise SystemExit(2) from exc
        raise
    return float(summary["final_drop"])


if __name__ == "__main__":
    main()
