"""The nominal guard of a blue-team fine-tune: validation that refuses a checkpoint which lost the nominal object.

Every few PPO iterations (and before the first) :class:`NominalGuard` scores the checkpoint on validation
episodes: the nominal object's (``val_trials_nominal``) and each CrashShape's (``val_trials``). Its score
for early stopping is the CrashShapes' mean, but a checkpoint whose nominal episodes show a regression
from the starting policy's (:func:`grt.blueteam.core.nominal_regressed`, by :class:`GuardRule`) ranks
below every checkpoint that does not. It writes ``val_nominal.json`` (the start's nominal episodes and
the rule), one ``validation.jsonl`` row per validation, and keeps the best validated checkpoints in
``candidates/`` for the confirmation (:mod:`grt.blueteam.finetune`).
"""

from __future__ import annotations

import json
import logging
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from grt.blueteam.core import Geometry, nominal_regressed, rank_candidates
from grt.blueteam.spec import StudySpec
from grt.fileio import atomic_path
from grt.tasks.base import SIM_ERROR

log = logging.getLogger("grt.blueteam")


@dataclass(frozen=True)
class GuardRule:
    """How a checkpoint's nominal episodes are compared with the start's (``blueteam.nominal_*``).

    Attributes:
        guard: ``fisher`` or ``tolerance`` (see :func:`grt.blueteam.core.nominal_regressed`).
        tolerance: the largest drop of the mean (``tolerance``, and any continuous score).
        alpha: the one-sided Fisher test's level.
        binary: the task's score is success (0 or 1 per episode).
    """

    guard: str = "fisher"
    tolerance: float = 0.05
    alpha: float = 0.05
    binary: bool = True

    @classmethod
    def of(cls, spec: StudySpec, task: dict) -> GuardRule:
        """The rule of a study's settings for ``task`` (its ``score`` decides ``binary``)."""
        return cls(spec.nominal_guard, spec.nominal_tolerance, spec.nominal_alpha,
                   str(task.get("score", "success")) == "success")

    def regressed(self, start: list[float], now: list[float]) -> tuple[bool, str]:
        """Whether the episodes ``now`` show a regression from ``start``, and why."""
        return nominal_regressed(start, now, self.guard, self.tolerance, self.alpha, self.binary)


def episodes(policy: dict, geometries: list[Geometry], seeds: list[int], evaluator) -> dict[str, list[float]]:
    """Each geometry's per-episode scores on ``seeds`` (simulator errors left out), on ``evaluator``'s
    workers with ``policy`` swapped in."""
    results = evaluator.evaluate([g.mesh for g in geometries], seeds, parts=[g.parts for g in geometries],
                                 policy=policy)
    errors = sum(r.sim_errors for r in results)
    if errors:
        log.warning("%d of %d episodes ended in a simulator error and are left out", errors,
                    len(seeds) * len(geometries))
    return {g.name: [float(t.score) for t in r.trials if t.mode != SIM_ERROR]
            for g, r in zip(geometries, results, strict=True)}


def read_rows(path: Path) -> list[dict]:
    """The rows of a JSON-lines file (``validation.jsonl``)."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def keep_candidate(out_dir: Path, path: Path, iteration: int, keep: int) -> None:
    """Keep the checkpoint just validated as ``candidates/it<N>.pt`` while it ranks among the ``keep``
    best validated ones (see :func:`grt.blueteam.core.rank_candidates`); drop those it displaces."""
    if keep <= 0:
        return
    top = _top(out_dir, keep)
    folder = out_dir / "candidates"
    folder.mkdir(exist_ok=True)
    if f"it{iteration}.pt" in top:
        shutil.copyfile(path, folder / f"it{iteration}.pt")
    _drop_candidates(out_dir, top)


def _top(out_dir: Path, keep: int) -> set[str]:
    """The file names in ``candidates/`` of the ``keep`` best rows of ``validation.jsonl``."""
    detail = out_dir / "validation.jsonl"
    rows = read_rows(detail) if detail.exists() else []
    return {f"it{r['iteration']}.pt" for r in rank_candidates(rows, keep)}


def _drop_candidates(out_dir: Path, top: set[str]) -> list[str]:
    """Remove the checkpoints of ``candidates/`` not named in ``top``; returns their names."""
    gone = sorted((f for f in (out_dir / "candidates").glob("it*.pt") if f.name not in top),
                  key=lambda f: (len(f.stem), f.stem))
    for f in gone:
        f.unlink()
    return [f"candidates/{f.name}" for f in gone]


class NominalGuard:
    """``checkpoint path -> validation score`` of a fine-tune (the ``score`` of a
    :class:`grt.rl.train.ValidationSpec`): the CrashShapes' mean validation score, for a checkpoint whose
    nominal validation shows no regression from the start (``nominal_guard``); one that does ranks below
    every one that does not (its score minus 2).

    Args:
        out_dir: the blue-team folder (``val_nominal.json``, ``validation.jsonl``, ``candidates/``).
        policy: the policy config; each checkpoint is swapped into the evaluator's workers.
        shapes: the nominal object first, then the CrashShapes.
        seeds: validation episode seeds; the nominal object plays the first ``nominal_trials``, each
            CrashShape the first ``crash_trials``.
        evaluator: a :class:`grt.evaluators.sim.SimEvaluator` of the task.
        rule: how the nominal episodes are judged.
        keep: validated checkpoints kept for the confirmation (0: none).
    """

    def __init__(self, out_dir: Path, policy: dict, shapes: list[Geometry], seeds: list[int], evaluator,
                 rule: GuardRule, crash_trials: int, nominal_trials: int, keep: int):
        self.out_dir, self.policy, self.shapes, self.seeds = out_dir, policy, shapes, seeds
        self.evaluator, self.rule, self.keep = evaluator, rule, int(keep)
        self.crash_trials, self.nominal_trials = int(crash_trials), int(nominal_trials)
        self.start_file = out_dir / "val_nominal.json"  # the nominal object's episodes before fine-tuning
        self.detail = out_dir / "validation.jsonl"

    def __call__(self, path: Path) -> float:
        per = self.validate(path)
        if not self.start_file.exists():  # the first validation is of the policy before any update
            self.start_file.write_text(json.dumps({"nominal": float(np.mean(per["nominal"])),
                                                   "scores": per["nominal"], **asdict(self.rule)}))
        crash = float(np.mean([np.mean(v) for k, v in per.items() if k != "nominal"]))
        regressed, why = self.regressed(json.loads(self.start_file.read_text()), per["nominal"])
        log.info("validation: CrashShapes %.3f, nominal %.3f (%s: %s)", crash, float(np.mean(per["nominal"])), why,
                 "ranked below every kept checkpoint" if regressed else "kept")
        iteration = int(torch.load(path, map_location="cpu", weights_only=False).get("iter", -1)) + 1
        with self.detail.open("a") as f:  # one row per validation, for validation.png and the confirmation
            f.write(json.dumps({"iteration": iteration, "nominal": float(np.mean(per["nominal"])),
                                "crashshapes": {k: float(np.mean(v)) for k, v in per.items() if k != "nominal"},
                                "regressed": bool(regressed), "why": why, "episodes": per}) + "\n")
        keep_candidate(self.out_dir, path, iteration, self.keep)
        return crash - 2.0 if regressed else crash

    def restart(self, validated: list[int]) -> list[str]:
        """Bring the guard's files back to what a training (fresh, or resumed from ``last.pt``) kept: the
        ``restart`` of its :class:`grt.rl.train.ValidationSpec`, ``validated`` the checkpoint iterations of the
        validations kept. The stopped attempt's other ``validation.jsonl`` rows go (a resume at iteration N
        keeps those up to N; one from 0 none, its run validating the untrained policy again, and then
        ``val_nominal.json`` goes too), with the ``candidates/`` no longer among the best, so the confirmation
        chooses among checkpoints of this run only. Iteration N's candidate, if it ranks and its file went
        (displaced by the stopped attempt's later ones), is ``last.pt`` again. Returns what went."""
        keep, dropped = {int(it) + 1 for it in validated}, []
        if self.detail.exists():
            rows = [(line, int(json.loads(line)["iteration"])) for line in self.detail.read_text().splitlines()
                    if line.strip()]
            later = [it for _, it in rows if it not in keep]
            if later:
                with atomic_path(self.detail) as tmp:
                    tmp.write_text("".join(f"{line}\n" for line, it in rows if it in keep))
                dropped.append(f"{len(later)} row{'s' if len(later) > 1 else ''} of validation.jsonl (iteration"
                               f"{'s' if len(later) > 1 else ''} {', '.join(map(str, later))})")
        if not keep and self.start_file.exists():
            self.start_file.unlink()
            dropped.append("val_nominal.json (the nominal episodes before fine-tuning: validated again)")
        if self.keep > 0 and (self.out_dir / "candidates").is_dir():
            top = _top(self.out_dir, self.keep)
            dropped += _drop_candidates(self.out_dir, top)
            last = self.out_dir / "last.pt"
            if last.exists():
                name = f"it{int(torch.load(last, map_location='cpu', weights_only=False)['iter']) + 1}.pt"
                if name in top and not (self.out_dir / "candidates" / name).exists():
                    shutil.copyfile(last, self.out_dir / "candidates" / name)
                    log.info("candidates/%s is last.pt again (the stopped attempt's later checkpoints had "
                             "displaced it)", name)
        return dropped

    def validate(self, path: Path) -> dict[str, list[float]]:
        """The checkpoint's validation episodes: ``{"nominal": [...], <CrashShape>: [...], ...}``."""
        checkpoint = {**self.policy, "checkpoint": str(path)}  # the workers swap in each checkpoint
        per = episodes(checkpoint, self.shapes[:1], self.seeds[:self.nominal_trials], self.evaluator)
        per.update(episodes(checkpoint, self.shapes[1:], self.seeds[:self.crash_trials], self.evaluator))
        return per

    def regressed(self, start: dict, nominal: list[float]) -> tuple[bool, str]:
        """The guard's verdict on the nominal episodes against the start (``val_nominal.json``)."""
        if "scores" in start:
            return self.rule.regressed(start["scores"], nominal)
        # a fine-tune started before the guard kept its episodes: its fixed tolerance
        return nominal_regressed([start["nominal"]], [float(np.mean(nominal))], "tolerance",
                                 float(start.get("tolerance", self.rule.tolerance)))
