"""The blue-team's episodes go through the configured evaluator (``evaluator=sim`` or ``evaluator=ray``).

The scoring, validation and confirmation episodes of ``python -m grt.blueteam`` are built by
:func:`grt.blueteam.core.make_evaluator` from the app's ``evaluator`` group; here on the toy task session of
the evaluator tests (no simulator), with a real Ray started on this machine. The whole fine-tune on the
simulator is tests/blueteam/test_blueteam.py's (evaluator=sim, the default).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from grt.blueteam.core import Geometry, make_evaluator
from grt.blueteam.guard import episodes
from grt.cli.blueteam import SEARCH_EVALUATOR_KEYS, rered_config
from grt.config import plain
from grt.evaluators.ray_pool import RayEvaluator
from grt.evaluators.sim import SimEvaluator
from tests.evaluators.conftest import u_shape
from tests.runner.conftest import compose_run

TOY_SESSIONS = Path(__file__).resolve().parents[1] / "evaluators"  # _toy_session.py, imported by the workers
SEEDS = list(range(6))


@pytest.fixture
def toy(monkeypatch):
    """``(task, policy, geometries)``: the toy session's configs and the U-shape, its collision part the hull
    of its left half (half its bounding box is inside: the toy policy's outcomes vary with the seed)."""
    import numpy as np

    monkeypatch.syspath_prepend(str(TOY_SESSIONS))  # spawned workers and a local Ray's actors inherit it
    task = {"name": "toy", "session": {"_target_": "_toy_session.ToySession"}}
    policy = {"_target_": "_toy_session.ToyPolicy", "fill": 0.5}
    mesh = u_shape()
    left = np.asarray(mesh.vertices)[np.asarray(mesh.vertices)[:, 0] <= 0]
    nominal = Geometry("nominal", mesh, [left], "nominal")
    return task, policy, [nominal]


def test_the_blueteam_app_composes_the_evaluator_group_with_its_workers():
    cfg = compose_run(["workers=3"], config_name="blueteam")
    assert cfg.evaluator._target_ == "grt.evaluators.sim.SimEvaluator" and cfg.evaluator.workers == 3
    cfg = compose_run(["evaluator=ray", "evaluator.address=10.0.0.1:6379", "evaluator.workers=8"],
                      config_name="blueteam")
    assert cfg.evaluator._target_ == "grt.evaluators.ray_pool.RayEvaluator"
    assert cfg.evaluator.address == "10.0.0.1:6379" and cfg.evaluator.workers == 8 and cfg.workers == 2


def test_validation_episodes_on_ray_equal_those_of_the_worker_processes(toy):
    task, policy, shapes = toy
    strict = {**policy, "fill": 0.9}  # a "checkpoint" swapped in, as the validation does for each one
    got = {}
    for choice in ("sim", "ray"):
        cfg = compose_run([f"evaluator={choice}", "workers=2"], config_name="blueteam")
        with make_evaluator(plain(cfg.evaluator), task, policy, progress=False) as ev:
            assert type(ev) is (RayEvaluator if choice == "ray" else SimEvaluator) and ev.workers == 2
            got[choice] = (episodes(policy, shapes, SEEDS, ev), episodes(strict, shapes, SEEDS, ev),
                           ev.backend_info()["backend"])
    assert got["sim"][2] == "pool" and got["ray"][2] == "ray"
    assert got["ray"][:2] == got["sim"][:2] and len(got["ray"][0]["nominal"]) == len(SEEDS)
    assert 0 < sum(got["sim"][0]["nominal"]) < len(SEEDS) and not any(got["sim"][1]["nominal"])  # swapped in


def test_the_re_red_team_runs_on_the_blueteams_backend_with_the_runs_collision_settings(tmp_path):
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from grt.config import validate

    run_cfg = compose_run(["task=insertion", "policy=insertion_state", "budget=smoke", "evaluator.collision=coacd"])
    bt = compose_run(["evaluator=ray", "evaluator.address=auto", "workers=3"], config_name="blueteam")
    saved = OmegaConf.to_container(run_cfg)  # the run's config as its folder keeps it
    cfg = rered_config(saved, tmp_path / "policy.pt", tmp_path / "rered", plain(bt.evaluator))
    validate(cfg)
    ev = cfg.evaluator
    assert ev._target_.endswith("RayEvaluator") and ev.address == "auto" and ev.workers == cfg.budget.workers == 3
    assert {k: ev[k] for k in SEARCH_EVALUATOR_KEYS} == {k: run_cfg.evaluator[k] for k in SEARCH_EVALUATOR_KEYS}
    assert ev.collision == "coacd" and cfg.policy.checkpoint == str(tmp_path / "policy.pt")
    assert cfg.paths.output_dir == str(tmp_path / "rered") and cfg.budget.seed == run_cfg.budget.seed
    assert instantiate(ev).func is RayEvaluator
    # without the blue-team's evaluator the run's own is kept
    assert rered_config(saved, tmp_path / "p.pt", tmp_path / "r").evaluator == run_cfg.evaluator
    assert saved == OmegaConf.to_container(run_cfg)  # the run's own config is not changed
