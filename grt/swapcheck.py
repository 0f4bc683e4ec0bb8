"""The swap check of a ManiSkill task, run with every red-team run, evaluation and blue-team study.

GRT red-teams a stock ManiSkill task through a copy of it: the stock actor replaced by the nominal mesh's
convex parts. :func:`swap_check` runs the policy on the nominal's episode seeds once more with the stock actor
(in the same worker sessions, so the cost is the nominal's trials once more) and compares the two runs seed by
seed (:mod:`grt.agreement`). A copy that disagrees stops the command before anything is saved, with one line
naming both figures and the ways on; ``swap_check.accept=true`` goes on and the record says so.

A measurement that passed is cached under ``<cache_dir>/swapcheck/`` by everything it depends on (the task's
config, the policy's config and checkpoint file, the nominal mesh, the seeds, the collision settings and the
source of GRT's task, policy and collision code), so repeated runs of the same task, policy, object and seeds
pay it once.

Tasks without a stock env (GRT's own grasp, insertion and drawer tasks), a nominal object other than the
task's own actor, and an evaluator that cannot load the stock actor are recorded as not checked, with why.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from pathlib import Path

import trimesh

from grt.agreement import SwapCheckError, SwapCheckSettings, compare, refusal
from grt.evaluators.base import CandidateResult, check_scored, stock_actor
from grt.fileio import write_text_atomic
from grt.geometry.mesh import mesh_hash
from grt.tasks import ACTOR_OBJECT, session_class

log = logging.getLogger(__name__)

CACHE = "swapcheck"
#: the evaluator settings that shape a trial's physics (as grt.runfolder's EVALUATOR_RESULTS)
_PHYSICS = ("collision", "coacd", "max_hull_vertices")


def not_checked(task: dict, object_spec: str) -> str | None:
    """Why the swap of this task and object cannot be checked (``None``: it can).

    A task has a stock env when its session class can build the stock actor (``nominal_object``: the
    ManiSkill sessions); the check compares that actor with its own geometry swapped in (``object=actor``).
    """
    name = task.get("name", "?")
    if getattr(session_class(task), "nominal_object", None) is None:
        return (f"no stock env: task={name} is GRT's own task (its env and object are built by GRT; there is no "
                "other copy to compare with)")
    if str(object_spec) != ACTOR_OBJECT:
        return (f"not checked: the nominal object is {object_spec}, not the stock env's own actor (object=actor); "
                "the check compares the stock actor with its own geometry swapped in")
    return None


def check_settings(task: dict, object_spec: str, settings: SwapCheckSettings) -> None:
    """Refuse, before anything runs, an override that has nothing to override.

    Raises:
        SwapCheckError: ``swap_check.accept=true`` for a task (or object) the check does not apply to.
    """
    why = not_checked(task, object_spec)
    if settings.accept and why is not None:
        raise SwapCheckError(f"swap_check.accept=true: {why}, so there is no disagreement to accept; drop "
                             "swap_check.accept")


def swap_check(task: dict, policy: dict, object_spec: str, mesh: trimesh.Trimesh, seeds: list[int], evaluator,
               settings: SwapCheckSettings, cache_dir: str | Path, evaluator_cfg: dict | None = None,
               nominal: dict | CandidateResult | None = None) -> tuple[dict, CandidateResult | None]:
    """Check the nominal swap against the stock actor on ``seeds``; refuse a disagreeing one.

    Args:
        task, policy: the task's and policy's configs (plain dicts).
        object_spec: the command's ``object`` (the check applies to ``actor``).
        mesh: the nominal object (meters, GRT's frame).
        seeds: the nominal evaluation's episode seeds.
        evaluator: the command's evaluator, started or not.
        settings: ``swap_check`` (:class:`grt.agreement.SwapCheckSettings`).
        cache_dir: ``paths.cache_dir``.
        evaluator_cfg: the evaluator's config (its physics settings enter the cache key).
        nominal: the nominal's trials when already scored (a journal record or a result): only the stock
            actor runs then.

    Returns:
        ``(record, nominal_result)``: the ``swap_check`` block of ``summary.json`` (:func:`grt.agreement.compare`
        plus ``cached``, ``wall_s``, ``key``; or ``{"stock": None, "note"}``) and the nominal's result when this
        call scored it (for the caller to journal instead of scoring it again), else ``None``.

    Raises:
        SwapCheckError: the swap disagrees and ``settings.accept`` is false.
        NothingScoredError: every trial of the stock actor (or the nominal) was a simulator error.
    """
    why = not_checked(task, object_spec)
    if why is None and not settings.enabled:
        why = "skipped (swap_check.enabled=false)"
    if why is None and not getattr(evaluator, "runs_stock", False):
        why = (f"not checked: {type(evaluator).__name__} cannot load the stock actor; python -m grt.calibrate "
               f"task={task.get('name', '?')} compares the two on worker processes")
    if why is not None:
        return {"stock": None, "note": why}, None
    key = cache_key(task, policy, mesh, seeds, evaluator_cfg)
    path = Path(cache_dir).expanduser() / CACHE / f"{key}.json"
    measured, cached, result, start = _cached(path, seeds), True, None, time.perf_counter()
    if measured is None:
        cached = False
        stock = stock_actor(mesh)
        if nominal is None:
            result, stock_result = evaluator.evaluate([mesh, stock], seeds)
            check_scored(result, "the nominal object")
        else:
            stock_result = evaluator.evaluate([stock], seeds)[0]
        check_scored(stock_result, "the stock actor (swap check)")
        swap_modes = _modes(result if nominal is None else nominal)
        measured = {"stock_modes": [t.mode for t in stock_result.trials], "swap_modes": swap_modes}
    record = {**compare(measured["stock_modes"], measured["swap_modes"], seeds, settings), "cached": cached,
              "wall_s": round(time.perf_counter() - start, 2), "key": key}
    if not record["passed"] and not settings.accept:
        raise SwapCheckError(refusal(task.get("name", "?"), record))
    if record["passed"] and not cached:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(path, json.dumps({"seeds": [int(s) for s in seeds], **measured}))
    return record, result


def cache_key(task: dict, policy: dict, mesh: trimesh.Trimesh, seeds: list[int], evaluator_cfg: dict | None) -> str:
    """The digest of everything a swap check's outcome depends on (see the module docstring)."""
    physics = {k: (evaluator_cfg or {}).get(k) for k in _PHYSICS}
    ckpt = policy.get("checkpoint") if isinstance(policy, dict) else None
    parts = {"task": task, "policy": policy, "checkpoint": _file_digest(ckpt), "mesh": mesh_hash(mesh.vertices, mesh.faces),
             "seeds": [int(s) for s in seeds], "physics": physics, "code": _code_digest()}
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:20]


def _cached(path: Path, seeds: list[int]) -> dict | None:
    """A passing measurement cached at ``path`` for these seeds, or ``None`` (none, or unreadable: measured again)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    ok = isinstance(data, dict) and data.get("seeds") == [int(s) for s in seeds] and all(
        isinstance(data.get(k), list) and len(data[k]) == len(seeds) for k in ("stock_modes", "swap_modes"))
    return data if ok else None


def _modes(nominal: dict | CandidateResult) -> list[str]:
    """The outcome mode per seed of the nominal's trials (a journal record or an evaluator result)."""
    if isinstance(nominal, CandidateResult):
        return [t.mode for t in nominal.trials]
    return [tr["mode"] for tr in nominal["trials"]]


def _file_digest(path) -> str | None:
    """The content digest of a checkpoint file (``None`` without one)."""
    if not isinstance(path, str) or not Path(path).is_file():
        return None
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def _code_digest() -> str:
    """The digest of GRT's task, policy and collision code: a change there may change a trial's outcome."""
    root = Path(__file__).resolve().parent
    files = sorted((root / "tasks").rglob("*.py")) + sorted((root / "policies").rglob("*.py")) + \
        [root / "evaluators" / "collision.py"]
    digest = hashlib.sha256()
    for f in files:
        digest.update(f.name.encode() + f.read_bytes())
    return digest.hexdigest()[:16]
