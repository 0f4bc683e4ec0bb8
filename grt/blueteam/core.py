"""Blue-teaming (paper Sec. "Blue-teaming", Table 3): fine-tune a red-teamed policy on its CrashShapes.

From a red-team run folder: the run's own resolved task and policy, its nominal object, its handles
and journal (each CrashShape is re-made from its journaled theta, bit for bit). The policy is
fine-tuned with PPO (rsl-rl) on a mix of CrashShapes and the nominal object (each episode draws one
shape; ``nominal_share`` of them the nominal), with early stopping on validation episodes, and then
scored before and after on the same held-out episodes: each CrashShape, the nominal object, and
held-out nearby shapes (failing candidates of the run that were not trained on, and fresh small
deformations of the CrashShapes).
"""

from __future__ import annotations

import json
import logging
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from grt.blueteam.spec import BlueTeamError, check_guard
from grt.evaluators.collision import make_collision
from grt.evaluators.sim import SimEvaluator
from grt.geometry.deform import ShapeDeformer
from grt.geometry.mesh import load_mesh
from grt.outputs import crash_records
from grt.plan import RunPlan
from grt.scores import ScoreSpec
from grt.selectors.base import HandleSet
from grt.targets import build
from grt.tasks import task_object

log = logging.getLogger(__name__)


@dataclass
class Geometry:
    """A named shape of the study: mesh (m), its convex parts, and where it comes from."""

    name: str
    mesh: trimesh.Trimesh
    parts: list[np.ndarray]
    role: str  # "crashshape" | "nominal" | "heldout"
    red_team_score: float | None = None


def load_run(run_dir: str | Path) -> tuple[RunPlan, list[dict]]:
    """The red-team run's plan (:func:`grt.config.saved_plan` of its config as it ran, migrated to the current
    format; the config itself is its ``config``) and its journal records.

    Raises:
        BlueTeamError: not a finished red-team run folder.
    """
    from grt.config import saved_plan
    from grt.journal import Journal
    from grt.runfolder.record import RUN_CONFIG, is_run_folder, load_run_config

    run_dir = Path(run_dir)
    journal = run_dir / "journal.jsonl"
    if not is_run_folder(run_dir) or not journal.exists() or not (run_dir / "handles.json").exists():
        raise BlueTeamError(f"{run_dir} is not a red-team run folder (it needs {RUN_CONFIG}, handles.json and "
                            "journal.jsonl): give run=outputs/<task>/<object>/<policy>/<selector>-<optimizer>/<time>")
    return saved_plan(load_run_config(run_dir), run_dir), Journal(journal).records


def run_geometry(run: RunPlan, cache_dir: str) -> tuple:
    """``(nominal, deformer, collision)`` of a red-team run (its plan, :func:`load_run`), prepared as the run
    did: its nominal mesh, the deformer over its handles (a journaled theta gives the candidate's mesh bit for
    bit) and its collision-part maker (CoACD cache under ``cache_dir``)."""
    nominal = load_mesh(task_object(run.task, run.object, cache_dir), scale=run.object_scale, settings=run.mesh)
    handles = HandleSet.from_json((run.run_dir / "handles.json").read_text())
    deformer = ShapeDeformer(nominal, handles.handles, handles.anchors, **run.deformer.options)
    ev = run.evaluator
    collision = make_collision(ev["collision"], nominal, ev["coacd"], f"{cache_dir}/coacd", ev["max_hull_vertices"])
    return nominal, deformer, collision


def make_evaluator(evaluator: dict, task: dict, policy: dict, progress: bool = True) -> SimEvaluator:
    """The blue-team's simulator evaluator: the one its config chooses (``evaluator=sim``, the default, or
    ``evaluator=ray``, e.g. with ``evaluator.address=HOST:PORT`` to run the episodes on a Ray cluster),
    with the app's ``workers`` (``conf/blueteam.yaml``). Every geometry of a study comes with its convex
    parts (CoACD, as the paper makes them), so the evaluator never decomposes one itself.

    Args:
        evaluator: the app's ``evaluator`` node (plain, :attr:`grt.blueteam.spec.StudySpec.evaluator`).
        task, policy: the red-team run's task and policy configs (plain).
        progress: show a progress bar per evaluation.
    """
    return build(evaluator, "evaluator", task=task, policy=policy, collision="coacd", progress=progress)


def trainable_checkpoint(policy_cfg: dict) -> str:
    """The rsl-rl checkpoint path of the run's policy.

    Raises:
        BlueTeamError: the policy is not an rsl-rl policy (an analytic planner, a user's predictor).
    """
    target = str(policy_cfg.get("_target_", ""))
    if not target.endswith("RslRlPolicy") or "checkpoint" not in policy_cfg:
        raise BlueTeamError(f"the run's policy ({target or 'unknown'}) cannot be fine-tuned: blue-teaming trains an "
                            "rsl-rl policy with PPO (e.g. policy=insertion_state); red-team one of those first")
    return str(policy_cfg["checkpoint"])


def select_crashshapes(records: list[dict], mode, top_k: int, failing_below: float, s0: float) -> list[dict]:
    """The journal records trained on.

    Args:
        mode: ``top1``, ``topk`` or ``all-failing`` (the lowest-scoring candidates with score <
            failing_below x S0), or the user's own choice: a list of candidate names (``it2_c5``, or the
            file names the run wrote, ``rank2_it2_c5.stl``), trained on whatever they scored.

    Raises:
        BlueTeamError: an unknown mode or name, or no failing candidate.
    """
    if not isinstance(mode, str):
        return _named(records, list(mode))
    failing = failing_records(records, failing_below, s0)
    if mode == "top1":
        chosen = failing[:1]
    elif mode == "topk":
        chosen = failing[:top_k]
    elif mode == "all-failing":
        chosen = failing
    elif _NAME.search(mode):
        return _named(records, [mode])
    else:
        raise BlueTeamError(f"blueteam.crashshapes={mode!r}: use top1, topk, all-failing or candidate names "
                            "such as [it2_c5,it3_c1]")
    if not chosen:
        raise BlueTeamError(f"the run found no CrashShape scoring below {failing_below:.0%} of "
                            f"S0 = {s0:.4g}: nothing to blue-team (red-team longer, or raise blueteam.failing_below)")
    return chosen


def failing_records(records: list[dict], failing_below: float, s0: float) -> list[dict]:
    """The run's explored candidates scoring below ``failing_below`` x S0, lowest first (maybe none)."""
    return [r for r in crash_records(records, len(records)) if r["score"] < failing_below * s0]


_NAME = re.compile(r"it(\d+)_c(\d+)")


def _named(records: list[dict], names: list) -> list[dict]:
    """The candidates named ``it<iteration>_c<candidate>`` (any text around it, e.g. a CrashShape file name)."""
    by_name = {name_of(r): r for r in records  # simulated candidates (an implausible one has no score)
               if r.get("theta") is not None and r["iteration"] > 0 and r["score"] == r["score"]}
    chosen = []
    for raw in names:
        match = _NAME.search(str(raw))
        rec = by_name.get(f"it{match[1]}_c{match[2]}") if match else None
        if rec is None:
            lowest = sorted(by_name.values(), key=lambda r: r["score"])[:5]
            raise BlueTeamError(f"blueteam.crashshapes: no candidate {raw!r} in the run's journal; name them "
                                f"it<iteration>_c<candidate>, e.g. the lowest-scoring: "
                                f"{', '.join(name_of(r) for r in lowest) or 'none'}")
        if rec not in chosen:
            chosen.append(rec)
    if not chosen:
        raise BlueTeamError("blueteam.crashshapes=[]: name at least one candidate, or use top1")
    return chosen


def distinct(records: list[dict], exclude: list[dict], count: int) -> list[dict]:
    """Up to ``count`` records not in ``exclude`` and not repeating a mesh already chosen."""
    seen = {r["mesh_hash"] for r in exclude}
    out = []
    for r in records:
        if r["mesh_hash"] not in seen and len(out) < count:
            out.append(r)
            seen.add(r["mesh_hash"])
    return out


def nominal_regressed(start: list[float], now: list[float], guard: str = "fisher", tolerance: float = 0.05,
                      alpha: float = 0.05, binary: bool = True) -> tuple[bool, str]:
    """Whether a checkpoint's nominal validation episodes show a regression from the start's, and why.

    ``fisher`` (binary scores): the checkpoint's successes are significantly fewer than the start's, by a
    one-sided Fisher exact test at ``alpha``: a regression is refused on evidence, not on one unlucky
    episode (measured: a 16-episode validation at 12/16 refused a checkpoint that succeeded on 30 of 32
    held-out episodes). ``tolerance``, and any continuous score: the mean fell more than ``tolerance``.

    Args:
        start, now: per-episode scores before fine-tuning and of the checkpoint (success: 0 or 1).
    """
    check_guard(guard)
    mean_start, mean_now = float(np.mean(start)), float(np.mean(now))
    if guard == "fisher" and binary:
        from scipy.stats import fisher_exact

        a, b = int(round(sum(start))), int(round(sum(now)))
        p = float(fisher_exact([[a, len(start) - a], [b, len(now) - b]], alternative="greater").pvalue)
        return p < alpha, f"{b}/{len(now)} against {a}/{len(start)} at the start, one-sided Fisher p = {p:.3f}"
    return (mean_start - mean_now > tolerance + 1e-9,
            f"{mean_now:.3f} against {mean_start:.3f} at the start, tolerance {tolerance:.3f}")


def rank_candidates(rows: list[dict], keep: int) -> list[dict]:
    """The ``keep`` best validated checkpoints among those the nominal guard kept, best first: by the
    CrashShapes' mean validation score, then the nominal's, then the later iteration (a tie keeps the
    more trained policy). A repeated iteration (a resumed fine-tune validates it again) counts once,
    its last validation."""
    last = {int(r["iteration"]): r for r in rows}
    kept = [r for r in last.values() if not r["regressed"]]
    key = lambda r: (float(np.mean(list(r["crashshapes"].values()))), float(r["nominal"]), int(r["iteration"]))  # noqa: E731
    return sorted(kept, key=key, reverse=True)[:max(0, int(keep))]


def choose_confirmed(candidates: list[dict], start: list[float], guard: str = "fisher", tolerance: float = 0.05,
                     alpha: float = 0.05, binary: bool = True) -> tuple[int, list[dict]]:
    """Choose among validated checkpoints with fresh episodes: the selection among many noisy
    validations favours a checkpoint whose validation was lucky (measured: a kept checkpoint read
    31/32 on the nominal validation and 26/32 on held-out episodes).

    Each candidate's validation and confirmation episodes are pooled, for the nominal object and for
    each CrashShape; the nominal guard is applied to the pooled nominal episodes against the start's
    pooled ones (the same seeds), and the choice is the best pooled CrashShape mean among the
    candidates that pass. When none passes, the one with the best pooled nominal score is chosen and
    marked ``passed: False``.

    Args:
        candidates: ``{"iteration", "nominal": [...], "crashshapes": {name: [...]}}`` each, episodes of
            validation and confirmation together.
        start: the policy before fine-tuning on the same nominal episodes.

    Returns:
        The chosen index and one row per candidate (``iteration``, ``nominal``, ``crashshapes``,
        ``passed``, ``why``, ``chosen``).
    """
    if not candidates:
        raise ValueError("no candidate checkpoint to confirm")
    rows = []
    for c in candidates:
        regressed, why = nominal_regressed(start, c["nominal"], guard, tolerance, alpha, binary)
        crash = {k: float(np.mean(v)) for k, v in c["crashshapes"].items()}
        rows.append({"iteration": int(c["iteration"]), "nominal": float(np.mean(c["nominal"])),
                     "nominal_episodes": len(c["nominal"]), "crashshapes": crash,
                     "crashshape_mean": float(np.mean(list(crash.values()))), "passed": not regressed, "why": why})
    passing = [i for i, r in enumerate(rows) if r["passed"]]
    if passing:
        pick = max(passing, key=lambda i: (rows[i]["crashshape_mean"], rows[i]["nominal"], rows[i]["iteration"]))
    else:
        pick = max(range(len(rows)), key=lambda i: (rows[i]["nominal"], rows[i]["crashshape_mean"]))
    for i, r in enumerate(rows):
        r["chosen"] = i == pick
    return pick, rows


def plot_validation(rows: list[dict], dest: str | Path, score_label: str = "success",
                    chosen: int | None = None) -> bool:
    """``validation.png``: each validation's CrashShape scores (each and their mean) and the nominal
    object's, against the PPO iteration; refused checkpoints (the nominal guard) are marked. Returns
    whether there was anything to draw.

    Args:
        rows: ``validation.jsonl`` rows: ``iteration``, ``crashshapes`` ({name: score}), ``nominal``,
            ``regressed``.
        chosen: the iteration of the exported checkpoint (after confirmation), marked with a star.
    """
    if not rows:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    its = np.array([r["iteration"] for r in rows])
    fig, ax = plt.subplots(figsize=(7.5, 3.6))
    for name in rows[0]["crashshapes"]:
        ax.plot(its, [r["crashshapes"].get(name, np.nan) for r in rows], "-", lw=1, alpha=0.45, label=name)
    mean = [float(np.mean(list(r["crashshapes"].values()))) for r in rows]
    ax.plot(its, mean, "o-", lw=2.2, color="tab:red", label="CrashShapes, mean")
    ax.plot(its, [r["nominal"] for r in rows], "s-", lw=2.2, color="black", label="nominal")
    bad = np.array([bool(r["regressed"]) for r in rows])
    if bad.any():
        ax.plot(its[bad], np.array([r["nominal"] for r in rows])[bad], "x", ms=11, mew=2.5, color="tab:orange",
                label="refused: nominal regressed")
    if chosen is not None and chosen in set(its.tolist()):
        at = int(np.flatnonzero(its == chosen)[-1])
        ax.plot([chosen], [mean[at]], "*", ms=18, color="gold", mec="black", label="exported, after confirmation")
    ax.set(xlabel="PPO iteration", ylabel=f"validation {score_label}", title="blue-team validation")
    ax.legend(fontsize=7, loc="lower right", ncol=2)
    fig.tight_layout()
    fig.savefig(dest, dpi=110)
    plt.close(fig)
    return True


def name_of(rec: dict) -> str:
    return f"it{rec['iteration']}_c{rec['candidate']}"


def write_table(out_dir: Path, rows: list[dict], score: ScoreSpec | str) -> None:
    """``table3.json`` (the rows) and ``table3.md`` (the paper's columns and ours).

    Args:
        score: the task's score (a bare name is a unit-less score): success rates print as %, other
            scores as themselves, in their unit.
    """
    score = ScoreSpec(name=score) if isinstance(score, str) else score
    (out_dir / "table3.json").write_text(json.dumps(rows, indent=1))
    pct = (lambda v: f"{100 * v:.1f}") if score.binary else score.fmt
    head = "| policy | geometry | Orig. | Blue. | Nominal before | Nominal after | Held-out before | Held-out after |"
    name = "success %" if score.binary else score.label
    lines = [f"Scores: {name}, same held-out episodes before and after.", "", head, "|" + "---|" * 8]
    for r in rows:
        lines.append(f"| {r['policy']} | {r['geometry']} | {pct(r['orig'])} | {pct(r['blue'])} | "
                     f"{pct(r['nominal_before'])} | {pct(r['nominal_after'])} | {pct(r['heldout_before'])} | "
                     f"{pct(r['heldout_after'])} |")
    (out_dir / "table3.md").write_text("\n".join(lines) + "\n")
