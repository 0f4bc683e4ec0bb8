"""The red-teaming loop: Algorithm 1 of the paper (lines 276-315) with the budget projection of
Algorithm 2 (appendix, lines 689-698), journaled candidate by candidate.

Resume works by replay: optimizers are deterministic given their seed, so re-running ``ask``/``tell``
with the journaled scores reproduces the search exactly; a candidate already in the journal is never
evaluated again (its stored theta must match the replayed one, which catches a changed config).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from grt.evaluators.base import NothingScoredError, check_scored
from grt.geometry.mesh import mesh_hash
from grt.journal import InOrder, Journal, JournalError
from grt.optimizers.base import Optimizer
from grt.optimizers.smoothness import project_to_budget, smoothness_score
from grt.racing import Racing, search_score, stopped

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from grt.evaluators.base import Evaluator
    from grt.geometry.deform import ShapeDeformer


SEED_RANGE = 2**31 - 1  # episode seeds are drawn from [0, SEED_RANGE)


def episode_seeds(seed: int, trials: int) -> list[int]:
    """The run's episode seeds: every candidate is scored on these same episodes (common random numbers).

    ``trials`` distinct seeds, drawn from ``default_rng(seed)`` in ``[0, 2**31 - 1)``; a draw that repeats an
    earlier seed (from ~17k-80k seeds on, a birthday collision) is skipped and the next draw taken, so the
    first ``n`` seeds are the same for every count ``trials >= n`` (and for the counts where no draw repeats,
    the plain draws, as they always were).
    """
    if trials < 1:
        raise ValueError(f"trials must be >= 1, got {trials}")
    if trials > SEED_RANGE // 2:
        raise ValueError(f"trials={trials}: at most {SEED_RANGE // 2} distinct episode seeds are drawn")
    rng = np.random.default_rng(seed)
    drawn = rng.integers(0, SEED_RANGE, size=trials)
    while True:  # the generator's stream, first occurrences in order, until there are enough
        _, first = np.unique(drawn, return_index=True)
        if len(first) >= trials:
            return [int(s) for s in drawn[np.sort(first)[:trials]]]
        drawn = np.concatenate([drawn, rng.integers(0, SEED_RANGE, size=trials - len(first))])


@dataclass
class RedTeamResult:
    """What a finished (or resumed) run found."""

    s0: float
    iteration_scores: list[list[float]]
    best_theta: np.ndarray | None
    best_score: float
    records: list[dict] = field(default_factory=list)
    evaluations: int = 0  # evaluated in this process (not replayed from the journal)


class RedTeamLoop:
    """Drive ``optimizer`` -> budget projection -> deformation -> simulated evaluation.

    Args:
        deformer: maps ``(N, H, 3)`` unit-cube displacements to metric meshes.
        optimizer: ask/tell search (seeded).
        evaluator: scores meshes on ``seeds`` with a black-box policy.
        journal: where every candidate goes as it finishes (and where a resume reads from).
        seeds: episode seeds shared by every candidate.
        iterations: ``T``.
        tau: Smoothness-Score budget in meters (``None``: off).
        complexity: ``mesh -> angular-deficit entropy`` (stored per candidate for ΔComplexity).
        on_candidate: called with each new record (progress bars, loggers).
        on_iteration: called with ``(t, scores)`` after each iteration.
        on_nominal: called with ``S0`` once it is journaled (evaluated or replayed); raising stops the run
            there (e.g. :func:`grt.scores.check_nominal_floor`).
        ci: interval method of each candidate's journaled ``ci95`` (the task's ``ci`` setting, see
            :func:`grt.metrics.score_interval`).
        validity: ``(nominal, mesh) -> dict`` with at least ``valid`` (e.g.
            :func:`grt.geometry.quality.candidate_validity`), stored in each record; a candidate that
            is not valid (self-intersecting, folded) is not simulated: its score is NaN, so it is never
            a CrashShape and the search sees it as the nominal object.
        racing: race each candidate's trials (:mod:`grt.racing`, ``budget.racing``; ``None``: off, every
            candidate runs every trial). A stopped candidate's record has ``race`` (trials run, why it
            stopped, its mean over them) and a NaN ``score``: no metric, CrashShape or confirmation counts
            it; the search is told its mean over the trials it ran.
        size_penalty, size_scale: a search for the smallest CrashShape (``budget.size_penalty``): the search is
            told ``score + size_penalty x S0 x SS / size_scale`` (SS: the Smoothness Score, m; ``size_scale``:
            the run's cap τ, m), the journal keeps the plain score; 0: off.
        nominal: the nominal object's result when it was already scored on ``seeds`` (the swap check scores
            it beside the stock actor, :mod:`grt.swapcheck`): journaled as it is instead of scored again.
    """

    def __init__(self, deformer: ShapeDeformer, optimizer: Optimizer, evaluator: Evaluator, journal: Journal,
                 seeds: list[int], iterations: int, tau: float | None = None,
                 complexity: Callable[[trimesh.Trimesh], float] | None = None,
                 on_candidate: Callable[[dict], None] | None = None,
                 on_iteration: Callable[[int, list[float]], None] | None = None, ci: str = "auto",
                 on_nominal: Callable[[float], None] | None = None,
                 validity: Callable[[trimesh.Trimesh, trimesh.Trimesh], dict] | None = None,
                 racing: Racing | None = None, size_penalty: float = 0.0, size_scale: float | None = None,
                 nominal=None):
        self.deformer, self.optimizer, self.evaluator = deformer, optimizer, evaluator
        self.size_penalty, self.size_scale = float(size_penalty), size_scale
        self.journal, self.seeds, self.iterations = journal, list(seeds), int(iterations)
        self.tau, self.complexity, self.ci = tau, complexity, ci
        self.on_candidate, self.on_iteration, self.on_nominal = on_candidate, on_iteration, on_nominal
        self.validity, self.racing, self.nominal = validity, racing, nominal
        if racing is not None and not getattr(evaluator, "races", False):
            log.warning("budget.racing=true: %s runs every trial of a candidate (it cannot stop one early), "
                        "so this run races nothing; evaluator=sim, ray and gpu race", type(evaluator).__name__)
            self.racing = None
        self.evaluations = 0

    def run(self) -> RedTeamResult:
        """Evaluate the nominal object, then ``T`` iterations of Algorithm 1."""
        for rec in self.journal.records:
            ran = [tr["seed"] for tr in rec["trials"]]
            if rec.get("valid", True) and ran != self.seeds and not (stopped(rec) and ran == self.seeds[:len(ran)]):
                self._mismatch(rec["iteration"], rec["candidate"], "its episode seeds differ (budget.trials "
                               "or budget.seed changed)")
        s0 = self._nominal_score()
        if not np.isfinite(s0):  # a journal written before such a record was kept out of it
            first = next((tr.get("error") for tr in self.journal.get(0, 0)["trials"] if tr.get("error")), None)
            raise NothingScoredError(
                f"every trial on the nominal object ended in sim_error ({first or 'no reason recorded'}), and the "
                f"journal {self.journal.path} keeps that record: once the cause is fixed, move the journal away "
                f"(mv {self.journal.path} {self.journal.path.with_suffix('.failed.jsonl')}) and resume, which "
                "evaluates the nominal object again")
        if self.on_nominal:
            self.on_nominal(s0)
        self._s0 = s0
        history: list[list[float]] = []
        for t in range(1, self.iterations + 1):
            thetas = self.optimizer.ask()  # mutate: floor(gamma M) handles per candidate (TOPDM)
            thetas = project_to_budget(thetas, self.tau, self.deformer.meters_per_unit)
            scores, told = self._population_scores(t, thetas)
            # A candidate the simulator could not score (all trials sim_error, NaN) or an implausible one
            # (self-intersecting, not simulated, NaN) is no CrashShape: the search sees it as the nominal
            # object, so it is never an elite by accident. A raced-out one: its mean over the trials it ran.
            search = np.where(np.isfinite(told), told, s0) + self._penalty(thetas, s0)
            self.optimizer.tell(thetas, search)  # keep ceil(rho N) elites, replicate
            history.append([float(x) for x in scores])
            if self.on_iteration:
                self.on_iteration(t, scores)
        return RedTeamResult(s0=s0, iteration_scores=history, best_theta=self.optimizer.best_theta,
                             best_score=self.optimizer.best_score, records=list(self.journal.records),
                             evaluations=self.evaluations)

    # ---------------------------------------------------------------------------------------------
    def _penalty(self, thetas: np.ndarray, s0: float) -> np.ndarray:
        """What the search adds to each candidate's score for its size (``budget.size_penalty``): ``lambda x S0 x
        SS / size_scale``, so that of two candidates that fail alike it keeps the smaller (0 when off)."""
        if not self.size_penalty or not self.size_scale:
            return np.zeros(len(thetas))
        ss = smoothness_score(thetas, self.deformer.meters_per_unit)
        return self.size_penalty * abs(s0) * ss / self.size_scale

    def _nominal_score(self) -> float:
        mesh = self.deformer.mesh
        rec = self.journal.get(0, 0)
        if rec is None:
            rec = self._evaluate(0, [(0, np.zeros((self.deformer.handles.size, 3)), mesh)])[0]
        elif rec["mesh_hash"] != mesh_hash(mesh.vertices, mesh.faces):
            self._mismatch(0, 0, "the nominal object differs (object= changed)")
        return float(rec["score"])

    def _population_scores(self, t: int, thetas: np.ndarray) -> tuple[list[float], list[float]]:
        """Scores of iteration ``t``'s candidates (replayed from the journal, the others evaluated together)
        and what the search is told (the same, but a raced-out candidate's mean over the trials it ran)."""
        scores, todo = [float("nan")] * len(thetas), []
        told = [float("nan")] * len(thetas)
        for i, theta in enumerate(thetas):
            rec = self.journal.get(t, i)
            if rec is None:
                todo.append((i, theta, self.deformer.meshes(theta[None])[0]))
                continue
            if not np.allclose(np.asarray(rec["theta"]), theta, rtol=1e-9, atol=1e-12):
                self._mismatch(t, i, "its parameters differ (optimizer, seed, handles or budget changed)")
            scores[i], told[i] = float(rec["score"]), search_score(rec)
        for rec in self._evaluate(t, todo) if todo else []:
            scores[rec["candidate"]], told[rec["candidate"]] = float(rec["score"]), search_score(rec)
        return scores, told

    def _mismatch(self, t: int, i: int, why: str) -> None:
        raise JournalError(f"{self.journal.path}: iteration {t} candidate {i} of the journal was not made by this "
                           f"run's config: {why}. `python -m grt.run resume=DIR` alone resumes with the run's own config "
                           "(run_config.yaml); otherwise start a new run.")

    def _evaluate(self, t: int, todo: list[tuple[int, np.ndarray, trimesh.Trimesh]]) -> list[dict]:
        """Check, simulate and journal candidates ``(i, theta, mesh)`` of iteration ``t``; their records in order.

        The plausible ones are simulated in one evaluator call (a whole population keeps up to population
        x trials workers busy); each is journaled as soon as it and every candidate before it are done, so
        the journal's order never depends on which worker finished first, and a killed run loses only the
        candidates still running. A candidate's ``wall_s`` is its plausibility check plus its trials'
        worker seconds.
        """
        checks = []
        for _, _, mesh in todo:
            start = time.perf_counter()
            validity = self.validity(self.deformer.mesh, mesh) if self.validity else {}
            checks.append((validity, time.perf_counter() - start))
        def write(rec: dict) -> None:
            self.journal.append(rec)
            if self.on_candidate:
                self.on_candidate(rec)

        order = InOrder(write)

        def finish(k: int, result) -> None:
            if t == 0 and result is not None:  # nothing scored on the nominal object: never journaled, so that a
                check_scored(result, "the nominal object")  # resume, once the cause is fixed, evaluates it again
            order.done(k, self._record(t, *todo[k], *checks[k], result))

        # the nominal object is always scored; an implausible candidate is not simulated (NaN)
        sim = [k for k, (validity, _) in enumerate(checks) if validity.get("valid", True) or t == 0]
        for k in range(len(todo)):
            if k not in sim:
                finish(k, None)
        if t == 0 and self.nominal is not None:  # already scored on these seeds (the swap check)
            finish(0, self.nominal)
            sim, self.evaluations = [], self.evaluations + 1
        if sim:
            meshes, on_result = [todo[k][2] for k in sim], lambda j, result: finish(sim[j], result)
            if self.racing is not None and t > 0:  # the nominal runs every trial
                race = self.racing.for_iteration(len(self.seeds), self._s0, self.journal.records, t)
                self.evaluator.evaluate_each(meshes, self.seeds, on_result, race=race)
            else:
                self.evaluator.evaluate_each(meshes, self.seeds, on_result)
            self.evaluations += len(sim)
        if len(order.written) != len(todo):
            raise RuntimeError(f"the evaluator returned {len(order.written)} of {len(todo)} candidates' results")
        return order.written

    def _record(self, t: int, i: int, theta: np.ndarray, mesh: trimesh.Trimesh, validity: dict, check_s: float,
                result) -> dict:
        """A candidate's journal record (``result`` None: not simulated)."""
        if result is not None:
            trials = [{"seed": o.seed, "score": float(o.score), "success": bool(o.success), "mode": o.mode,
                       **({"error": str(o.info["error"])[:500]} if o.info.get("error") else {}),
                       **({"note": str(o.info["note"])[:300]} if o.info.get("note") else {})}
                      for o in result.trials]
            score, ci95, outcomes = float(result.score), list(result.ci95(self.ci)), result.outcomes
            wall = check_s + float(result.wall_s)
            race = result.info.get("race")
            if race is not None:  # racing: the trials it ran; a stopped one has no full-trial score
                race = {**race, "score": score, "ci95": ci95}
                if race["stopped"]:
                    score, ci95 = float("nan"), [float("nan")] * 2
        else:
            score, ci95, outcomes, trials, wall = float("nan"), [float("nan")] * 2, {}, [], check_s
            race = None
        return {
            "iteration": t, "candidate": i, "score": score, "ci95": ci95, "outcomes": outcomes,
            **({"race": race} if race is not None else {}),
            **validity,
            "theta": np.asarray(theta).tolist(),
            "smoothness_m": float(smoothness_score(theta, self.deformer.meters_per_unit)),
            "entropy": float(self.complexity(mesh)) if self.complexity else None,
            "mesh_hash": mesh_hash(mesh.vertices, mesh.faces),
            "trials": trials, "wall_s": round(wall, 3),
        }
