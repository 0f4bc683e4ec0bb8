"""evaluator=gpu: the population split, the candidate/seed <-> sub-scene mapping, the batched episode protocol,
the refusals, and the whole path on physx_cpu (one sub-scene per env) against the task's own trials.

The tests marked ``gpu`` run the same on physx_cuda, many sub-scenes per env; they need CUDA and skip without.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import trimesh

from grt.evaluators.gpu import GpuEvaluator, GpuEvaluatorError, check_batched, objects_of, plan_batches

HERE = Path(__file__).parent
SEEDS = [11, 12, 13, 14, 15]


def _cuda() -> bool:
    import torch

    return torch.cuda.is_available()


gpu = pytest.mark.gpu
needs_cuda = pytest.mark.skipif(not _cuda(), reason="no CUDA device: torch.cuda.is_available() is False here "
                                                     "(run on a GPU machine: scripts/gpu_check.sh)")


# --------------------------------------------------------------------------- the population split
@pytest.mark.parametrize(("candidates", "trials", "max_envs", "sizes"), [
    (10, 128, 2048, [1280]),          # the paper's insertion population: one env
    (10, 128, 512, [427, 427, 427]),  # split into equal batches, the last padded by one repeat
    (1, 4096, 2048, [2048, 2048]),    # one candidate over two batches (the drawer's 4096 trials)
    (3, 2, 1, [1] * 6),               # physx_cpu: one sub-scene per env
])
def test_the_population_split_lays_every_pair_out_once_in_equal_batches(candidates, trials, max_envs, sizes):
    seeds = list(range(100, 100 + trials))
    pairs = [(c, s) for c in range(candidates) for s in seeds]
    batches = plan_batches(pairs, max_envs)
    assert [len(b) for b in batches] == sizes and all(len(b) <= max_envs for b in batches)
    real = [(c, s) for b in batches for c, s in zip(b.jobs[:b.real], b.seeds[:b.real], strict=True)]
    assert real == pairs  # each pair once, in order
    for b in batches:  # padding repeats the batch's last real pair
        assert set(zip(b.jobs[b.real:], b.seeds[b.real:], strict=True)) <= {(b.jobs[b.real - 1], b.seeds[b.real - 1])}


def test_a_batch_loads_each_candidate_once_and_maps_every_sub_scene_to_it():
    pairs = [(c, s) for c in (4, 7, 9) for s in (1, 2)]  # six pairs: two batches of three
    first, second = plan_batches(pairs, 4)
    order, assignment = objects_of(first)  # (4, 1) (4, 2) (7, 1)
    assert order == [4, 7] and assignment == [0, 0, 1] and second.seeds == (2, 1, 2)
    order, assignment = objects_of(second)  # (7, 2) (9, 1) (9, 2)
    assert order == [7, 9] and [order[a] for a in assignment] == list(second.jobs)
    with pytest.raises(ValueError, match="max_envs"):
        plan_batches([(0, 1)], 0)
    assert plan_batches([], 8) == []


# --------------------------------------------------------------------------- the batched protocol (toy)
@pytest.fixture
def toy(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    from _batched_toy import Greedy, PointMassBatch

    return PointMassBatch, Greedy


def _box(size: float) -> trimesh.Trimesh:
    mesh = trimesh.creation.box([size, size, size])
    mesh.apply_translation([0.0, 0.0, size / 2])
    return mesh


def _same(a, b) -> bool:
    strip = [{k: v for k, v in dataclasses.asdict(o).items()} | {"info": {k: v for k, v in o.info.items()
                                                                            if k != "wall_s"}} for o in (a, b)]
    return strip[0] == strip[1]


def test_sub_scenes_run_as_the_one_env_episodes_of_their_seeds(toy):
    """N episodes at once (different objects, seeds; one ends early, one errs, one cannot start, one gives up)
    end exactly as each run alone: an ended sub-scene idles, the others go on."""
    session_cls, greedy = toy
    objects = [(_box(0.06), [np.zeros((4, 3))]), (_box(0.3), [np.zeros((4, 3))])]
    seeds, assignment = [3, 4, 5, 6, 7], [0, 1, 0, 1, 1]
    batched = session_cls(greedy(), num_envs=5, nan_on=(5,), unreachable=(6,), give_up=1.5)
    batched.load_objects(objects, assignment)
    together = batched.run_episodes(seeds)
    alone = []
    for seed, j in zip(seeds, assignment, strict=True):
        single = session_cls(greedy(), nan_on=(5,), unreachable=(6,), give_up=1.5)
        single.load_object(*objects[j])
        alone.append(single.run_trial(seed))
    assert all(_same(a, b) for a, b in zip(together, alone, strict=True)), (together, alone)
    modes = [o.mode for o in together]
    assert modes[2] == "sim_error" and "non-finite distance" in together[2].info["error"]
    assert modes[3] == "sim_error" and together[3].info == {"error": "RuntimeError: seed 6 cannot start",
                                                            "steps": 0, "wall_s": together[3].info["wall_s"]}
    assert len({o.info["steps"] for o in together}) > 1 and set(modes) - {"sim_error"}, modes
    assert batched.policy.batches == [seeds]  # the policy starts the batch once, with every seed


def test_a_non_finite_action_ends_its_own_sub_scene_naming_the_policy(toy):
    """A policy's NaN action for one sub-scene is that episode's sim_error, naming the policy (issue 40, as a
    single trial's); the other sub-scenes run on as each runs alone. A misshapen batch fails every episode."""
    session_cls, greedy = toy

    class NaNOnSecond(greedy):
        def act(self, obs):
            actions = super().act(obs)
            actions[1] = np.nan
            return actions

    objects = [(_box(0.06), [np.zeros((4, 3))])]
    batched = session_cls(NaNOnSecond(), num_envs=3)
    batched.load_objects(objects, [0, 0, 0])
    together = batched.run_episodes([3, 4, 5])
    assert together[1].mode == "sim_error" and "NaNOnSecond returned a non-finite action [nan, nan]" in \
        together[1].info["error"] and together[1].info["steps"] == 0
    for i, seed in ((0, 3), (2, 5)):
        single = session_cls(greedy())
        single.load_object(*objects[0])
        assert _same(together[i], single.run_trial(seed))

    class Misshapen(greedy):
        def act(self, obs):
            return super().act(obs)[:, :1]

    batched = session_cls(Misshapen(), num_envs=2)
    batched.load_objects(objects, [0, 0])
    assert all(o.mode == "sim_error" and "returned actions of shape (2, 1)" in o.info["error"]
               for o in batched.run_episodes([3, 4]))


def test_the_evaluator_maps_candidates_and_seeds_to_sub_scenes_and_back(toy):
    """Three candidates x five seeds in batches of four: every trial lands on its candidate and seed as the
    candidate alone scores it, each candidate is reported once as soon as its last batch is done."""
    session_cls, greedy = toy
    task = {"name": "point_mass", "session": {"_target_": "_batched_toy.PointMassBatch", "give_up": 1.5}}
    policy = {"_target_": "_batched_toy.Greedy"}
    meshes = [_box(0.06), _box(0.3), _box(0.12)]
    parts = [[np.asarray(m.vertices)] for m in meshes]
    reported = []
    with GpuEvaluator(task, policy, collision="coacd", backend="physx_cpu", max_envs=4, recreate_every=2,
                      progress=False) as ev:
        results = ev.evaluate(meshes, SEEDS, parts=parts, on_result=lambda i, r: reported.append(i))
        info = ev.backend_info()
    assert reported == [0, 1, 2]  # candidate 0 ends in batch 2, candidate 1 in batch 3, candidate 2 in batch 4
    assert info["batches"] == 4 and info["sub_scenes"] == 16 and info["envs_built"] == 2  # rebuilt after 2 batches
    for mesh, result in zip(meshes, results, strict=True):
        single = session_cls(greedy(), give_up=1.5)
        single.load_object(mesh, [])
        assert all(_same(t, single.run_trial(s)) for t, s in zip(result.trials, SEEDS, strict=True))
        assert [t.seed for t in result.trials] == SEEDS and result.info["evaluator"] == "gpu"
    assert len({r.score for r in results}) > 1  # the objects matter


class StopWhenAllSucceed:
    """A race that stops a candidate at a look when every trial so far succeeded (the evaluator's side only)."""

    at = (2, 4)

    def stop(self, scores, errors=0):
        return {"stopped": "test", "n": len(scores)} if len(scores) in self.at and min(scores) == 1.0 else None


def test_a_gpu_evaluation_races_its_candidates_in_rounds_of_sub_scenes(toy):
    """Racing on evaluator=gpu: each round of the candidates still running is one set of batches; a stopped
    candidate takes no more sub-scenes, and the trials it ran are its first seeds' outcomes, as without racing."""
    task = {"name": "point_mass", "session": {"_target_": "_batched_toy.PointMassBatch", "give_up": 1.5}}
    policy = {"_target_": "_batched_toy.Greedy"}
    meshes = [_box(0.06), _box(0.3), _box(0.12)]
    parts = [[np.asarray(m.vertices)] for m in meshes]
    with GpuEvaluator(task, policy, collision="coacd", backend="physx_cpu", max_envs=8, progress=False) as ev:
        full = ev.evaluate(meshes, SEEDS, parts=parts)
        before = ev.backend_info()
        raced = ev.evaluate_each(meshes, SEEDS, lambda i, r: None, race=StopWhenAllSucceed())
        after = ev.backend_info()
    ran = [r.info["race"]["trials"] for r in raced]
    assert [r.info["race"]["stopped"] for r in raced] == ["test" if n < len(SEEDS) else None for n in ran]
    assert 2 in ran and len(SEEDS) in ran, ran  # one stopped after its first round, one ran every trial
    for whole, part, n in zip(full, raced, ran, strict=True):
        assert [t.seed for t in part.trials] == SEEDS[:n]
        assert all(_same(a, b) for a, b in zip(part.trials, whole.trials, strict=False))
    assert after["sub_scenes"] - before["sub_scenes"] == sum(ran)  # a stopped candidate took no more sub-scenes
    assert after["batches"] - before["batches"] == 3  # the rounds ending at seeds 2, 4 and 5, one batch each


# --------------------------------------------------------------------------- refusals
def test_tasks_and_policies_that_cannot_run_batched_are_refused_in_one_line():
    insertion = {"name": "insertion", "session": {"_target_": "grt.tasks.insertion.InsertionSession"}}
    grasp = {"name": "grasp", "session": {"_target_": "grt.tasks.grasp.GraspSession"}}
    with pytest.raises(GpuEvaluatorError, match="task=grasp .*evaluator=sim"):
        check_batched(grasp, {"_target_": "grt.policies.antipodal.AntipodalGraspPolicy"})
    with pytest.raises(GpuEvaluatorError, match="AntipodalGraspPolicy is per-env .*evaluator=sim"):
        check_batched(insertion, {"_target_": "grt.policies.antipodal.AntipodalGraspPolicy"})
    with pytest.raises(GpuEvaluatorError, match="physx_cpu runs 1 sub-scene per env.*max_envs=1"):
        check_batched(insertion, {"_target_": "grt.policies.servo.ServoInsertionPolicy"}, "physx_cpu", 4)
    check_batched(insertion, {"_target_": "grt.policies.servo.ServoInsertionPolicy"}, "physx_cuda", 4096)
    push = {"name": "push_cube", "session": {"_target_": "grt.tasks.maniskill.session.ManiSkillSession"}}
    with pytest.raises(GpuEvaluatorError, match="EnvDriverPolicy is per-env .*motion planner"):
        check_batched(push, {"_target_": "grt.policies.base.EnvDriverPolicy"})  # ManiSkill's motion planners
    check_batched(push, {"_target_": "grt.policies.maniskill_experts.PushToGoalPolicy"}, "physx_cuda", 4096)


@pytest.mark.skipif(_cuda(), reason="this machine has CUDA: the refusal without it cannot be seen here")
def test_a_run_on_evaluator_gpu_without_cuda_is_refused_before_it_writes(tmp_path):
    from grt.runner import run
    from tests.runner.conftest import compose_run

    out = tmp_path / "run"
    cfg = compose_run(["task=insertion", "policy=insertion_servo", "evaluator=gpu", "budget=smoke",
                       f"paths.output_dir={out}"])
    with pytest.raises(GpuEvaluatorError, match="torch sees none.*evaluator=sim"):
        run(cfg)
    assert not out.exists() or not any(out.iterdir())


# --------------------------------------------------------------------------- the real simulator
def _plugs():
    from grt.evaluators.collision import make_collision
    from grt.objects import get_object

    plug = get_object("usb_plug")
    bent = plug.copy()
    v = bent.vertices.copy()
    v[(v[:, 2] > 0.013) & (v[:, 1] > 0), 1] += 0.007  # the grip bulges: the plug sits off-center, the servo misses
    bent.vertices = v
    collision = make_collision("fast", plug, None, None, 64)
    return [plug, bent], [collision.parts(plug), collision.parts(bent)]


INSERTION = {"name": "insertion", "session": {"_target_": "grt.tasks.insertion.InsertionSession",
                                              "socket_object": "usb_plug", "cloud_points": 0,
                                              "max_steps": 40}}
SERVO = {"_target_": "grt.policies.servo.ServoInsertionPolicy"}


@pytest.mark.sim
def test_on_physx_cpu_the_gpu_path_scores_each_candidate_as_its_own_trials_do():
    """The whole evaluator=gpu path on ManiSkill's CPU simulation (one sub-scene per env): a nominal and a
    deformed plug give, trial for trial, what the insertion session gives for each alone; a plug the task
    refuses to load (too wide for the fingers) fails its trials as a CPU worker records them."""
    from grt.policies.servo import ServoInsertionPolicy
    from grt.tasks.insertion import InsertionSession

    meshes, parts = _plugs()
    wide = meshes[0].copy()
    wide.apply_scale([1.0, 9.0, 1.0])
    seeds = [3, 4]
    with GpuEvaluator(INSERTION, SERVO, nominal=meshes[0], backend="physx_cpu", max_envs=1, progress=False) as ev:
        results = ev.evaluate([*meshes, wide], seeds, parts=[*parts, parts[0]])
        assert ev.backend_info()["batches"] == 4  # the refused plug takes no sub-scene
    refused = results.pop()
    assert refused.outcomes == {"sim_error": 2} and refused.trials[0].info["error"].startswith(
        "load_object failed: PlugFitError: the plug's grip is"), refused.trials[0].info
    session = InsertionSession(ServoInsertionPolicy(), socket_object="usb_plug", cloud_points=0, max_steps=40)
    try:
        for mesh, p, result in zip(meshes, parts, results, strict=True):
            session.load_object(mesh, p)
            assert all(_same(t, session.run_trial(s)) for t, s in zip(result.trials, seeds, strict=True)), result
    finally:
        session.close()
    assert results[0].success_rate == 1.0 and results[1].success_rate == 0.0, [r.outcomes for r in results]


@pytest.mark.sim
def test_a_red_team_run_on_evaluator_gpu_races_its_trials_on_the_cpu(tmp_path):
    """budget.racing=true with evaluator=gpu (physx_cpu, one sub-scene): candidates stop after their first round,
    and summary.json counts what racing saved (no 'nothing was raced' note). With a crash margin of 0.99 only a
    candidate failing every trial would be a CrashShape: one success in its first round stops it."""
    import json

    from grt.runner import run
    from tests.runner.conftest import compose_run

    cfg = compose_run(["task=insertion", "policy=insertion_servo", "evaluator=gpu", "evaluator.backend=physx_cpu",
                       "evaluator.max_envs=1", "budget=smoke", "budget.trials=4", "budget.racing=true",
                       "budget.race_rounds=2", "task.crash_margin=0.99", "task.session.max_steps=40",
                       "task.nominal_floor=null", f"paths.output_dir={tmp_path}"])
    run(cfg)
    summary = json.loads((tmp_path / "summary.json").read_text())
    records = [json.loads(line) for line in (tmp_path / "journal.jsonl").read_text().splitlines()]
    raced = [r for r in records if r["iteration"] > 0 and r.get("race")]
    assert summary["evaluator"]["backend"] == "gpu" and summary["racing"]["stopped"] >= 1, summary.get("racing")
    assert all(len(r["trials"]) == (2 if r["race"]["stopped"] else 4) for r in raced)
    assert "nothing was raced" not in summary.get("note", "")


@gpu
@needs_cuda
def test_on_the_gpu_a_population_runs_in_sub_scenes_with_its_own_plugs():
    """physx_cuda, 2 plugs x 8 seeds in one env of 16 sub-scenes: the nominal plug inserts, the bulged one
    fails, and the journal's figures are there."""
    meshes, parts = _plugs()
    seeds = list(range(20, 28))
    with GpuEvaluator(INSERTION, SERVO, nominal=meshes[0], backend="physx_cuda", max_envs=16, progress=False) as ev:
        results = ev.evaluate(meshes, seeds, parts=parts)
        info = ev.backend_info()
    assert info["batches"] == 1 and info["sub_scenes"] == 16 and info["device"]
    assert results[0].success_rate >= 0.75 and results[1].success_rate <= 0.25, [r.outcomes for r in results]
    assert all(t.info["steps"] >= 1 for r in results for t in r.trials)


@gpu
@needs_cuda
def test_on_the_gpu_a_population_larger_than_max_envs_is_split_and_the_env_rebuilt():
    """3 batches of 4 sub-scenes (one env size), rebuilt after 2: the same plug scores the same in each."""
    meshes, parts = _plugs()
    seeds = list(range(30, 36))
    with GpuEvaluator(INSERTION, SERVO, nominal=meshes[0], backend="physx_cuda", max_envs=4, recreate_every=2, progress=False) as ev:
        results = ev.evaluate(meshes, seeds, parts=parts)
        info = ev.backend_info()
    assert info["batches"] == 3 and info["envs_built"] == 2
    assert results[0].success_rate > results[1].success_rate, [r.outcomes for r in results]


@gpu
@needs_cuda
def test_on_the_gpu_a_population_races_in_rounds_of_sub_scenes():
    """physx_cuda, 2 plugs x 8 seeds, racing: a candidate whose first trials all insert stops at a look and takes
    no more sub-scenes; the others run their next rounds as the next batches."""
    meshes, parts = _plugs()
    seeds = list(range(40, 48))
    with GpuEvaluator(INSERTION, SERVO, nominal=meshes[0], backend="physx_cuda", max_envs=16, progress=False) as ev:
        results = ev.evaluate_each(meshes, seeds, lambda i, r: None, race=StopWhenAllSucceed())
        info = ev.backend_info()
    ran = [r.info["race"]["trials"] for r in results]
    rounds = [2, 4, 8].index(max(ran)) + 1  # one batch per round the longest-running candidate ran
    assert info["sub_scenes"] == sum(ran) and info["batches"] == rounds, (ran, info)
    assert ran[0] in StopWhenAllSucceed.at, ([t.mode for t in results[0].trials], ran)  # the nominal plug inserts


def test_a_cpu_run_is_not_resumed_on_the_gpu_nor_the_reverse(tmp_path):
    """One journal, one physics: a run scored by CPU workers goes on with CPU workers (or evaluator=gpu on
    physx_cpu, whose trials are theirs bit for bit), not on the GPU."""
    from omegaconf import OmegaConf

    from grt.config import plain
    from grt.runfolder.record import ResumeError
    from grt.runfolder.resume import own_config, resume_overrides
    from tests.runner.conftest import compose_run

    run_dir = Path(__file__).resolve().parents[1] / "data" / "run_format1_toy"

    def resumed(*overrides: str):
        cfg = compose_run([*resume_overrides([f"resume={run_dir}", *overrides]), f"paths.output_dir={tmp_path}"])
        return OmegaConf.create(own_config(str(cfg.resume), plain(cfg)))

    with pytest.raises(ResumeError, match="CPU workers, this command would go on with evaluator=gpu"):
        resumed("evaluator=gpu")
    assert resumed("evaluator=gpu", "evaluator.backend=physx_cpu", "evaluator.max_envs=1").evaluator.max_envs == 1


@pytest.mark.sim
def test_the_gpu_path_drives_a_stock_maniskill_task_as_its_session_does(tmp_path):
    """Any ManiSkill task runs batched too: PushCube-v1 with its expert, through evaluator=gpu on physx_cpu,
    gives the session's own trial; a candidate None runs the env's stock actor."""
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from tests.runner.conftest import compose_run

    cfg = compose_run(["task=push_cube", "policy=push_cube_expert", f"paths.output_dir={tmp_path}"])
    task, policy = (OmegaConf.to_container(cfg[k], resolve=True) for k in ("task", "policy"))
    session = instantiate(task["session"], policy=instantiate(policy), _convert_="all")
    try:
        cube = session.nominal_object(**{k: v for k, v in task["session"].items() if k != "_target_"})
        parts = [np.asarray(cube.convex_hull.vertices)]
        session.load_object(cube, parts)
        alone = session.run_trial(3)
    finally:
        session.close()
    with GpuEvaluator(task, policy, collision="coacd", backend="physx_cpu", max_envs=1, progress=False) as ev:
        result, stock = ev.evaluate([cube, None], [3], parts=[parts, None])  # None: the stock actor
    assert _same(result.trials[0], alone) and alone.mode == "success", (result.trials, alone)
    assert stock.trials[0].mode == "success" and stock.info["parts"] == 0, stock.trials
