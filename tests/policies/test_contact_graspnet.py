"""Contact-GraspNet (the pretrained network of the cgn-pytorch wheel) on clouds of built-in objects."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from grt.objects import get_object
from grt.policies.base import GraspObservation
from grt.policies.cgn_net import (
    CGNWeightsError,
    ContactGraspNet,
    KDTreeOrder,
    checkpoint_path,
    farthest_point_sampling,
    knn_interpolate,
)
from grt.policies.contact_graspnet import ContactGraspNetPolicy

CAMERAS = 0.55 * np.c_[np.cos(np.deg2rad(30 + 60 * np.arange(6))) * 0.7,
                       np.sin(np.deg2rad(30 + 60 * np.arange(6))) * 0.7, np.full(6, 0.7)]


def scene_observation(mesh: trimesh.Trimesh, count: int = 8000, seed: int = 0) -> GraspObservation:
    """The object standing on the table (surface points a camera faces) and a table-top disc around it."""
    mesh = mesh.copy()
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    points, faces = trimesh.sample.sample_surface(mesh, count * 2, seed=seed)
    rays = CAMERAS[None] - points[:, None]
    facing = np.einsum("pci,pi->pc", rays / np.linalg.norm(rays, axis=-1, keepdims=True),
                       mesh.face_normals[faces])
    keep = facing.max(axis=1) > 0.05
    rng = np.random.default_rng(seed)
    disc = rng.uniform(-0.25, 0.25, (12000, 2))
    lo, hi = mesh.bounds[0, :2] - 0.005, mesh.bounds[1, :2] + 0.005
    disc = disc[(np.linalg.norm(disc, axis=1) < 0.25) & ~np.all((disc > lo) & (disc < hi), axis=1)]
    return GraspObservation(points=points[keep][:count], viewpoints=CAMERAS[facing.argmax(axis=1)][keep][:count],
                            table_z=0.0, context=np.c_[disc, np.zeros(len(disc))])


@pytest.fixture(scope="module")
def policy():
    return ContactGraspNetPolicy(num_points=12000)


@pytest.fixture(scope="module")
def mug_obs():
    return scene_observation(get_object("mug"))


def test_farthest_point_sampling_is_the_greedy_max_min_order():
    pos = torch.from_numpy(np.random.default_rng(0).uniform(size=(2, 300, 3)).astype(np.float32))
    idx = farthest_point_sampling(pos, 20)
    for b in range(2):
        p = pos[b].numpy().astype(np.float64)
        chosen, dist = [0], np.linalg.norm(p - p[0], axis=1)
        for _ in range(19):
            chosen.append(int(dist.argmax()))
            dist = np.minimum(dist, np.linalg.norm(p - p[chosen[-1]], axis=1))
        assert idx[b].tolist() == chosen
    seeded = [farthest_point_sampling(pos, 5, [torch.Generator().manual_seed(s) for s in (3, 4)]) for _ in "ab"]
    assert torch.equal(*seeded)


REFERENCE = Path(__file__).parents[1] / "data" / "cgn" / "reference.npz"


def test_ball_neighbors_are_the_ones_torch_cluster_keeps():
    """torch-cluster 1.6.3's radius(max_num_neighbors=16) on 800 points, recorded (scripts/cgn_reference.py)."""
    ref = np.load(REFERENCE)
    small = ref["small"]
    (idx, valid), = KDTreeOrder(small).first_in_ball(small[:50], (0.05,), 16)
    expected = [set() for _ in range(50)]
    for row, col in zip(ref["radius_row"], ref["radius_col"], strict=True):
        expected[row].add(int(col))
    assert [set(idx[m][valid[m]].tolist()) for m in range(50)] == expected
    d = np.linalg.norm(small[:50, None] - small[None], axis=-1)
    full = [m for m in range(50) if (d[m] < 0.05).sum() > 16]
    assert full, "some balls overflow: the k-d tree's order decides which 16 are kept"
    # ... and those are not simply the 16 nearest
    assert any(set(idx[m].tolist()) != set(np.argsort(d[m])[:16].tolist()) for m in full)


def test_network_reproduces_the_reference_implementation():
    """cgn-pytorch's own CGN on torch-geometric 2.4.0 + torch-cluster 1.6.3 (farthest-point start 0), recorded."""
    ref = np.load(REFERENCE)
    net = ContactGraspNet.pretrained()
    out = net(torch.from_numpy(ref["cloud"])[None])
    np.testing.assert_array_equal(out["index"][0].numpy(), ref["fps"])
    np.testing.assert_allclose(out["logits"][0].numpy(), ref["logits"], atol=2e-3, rtol=1e-3)
    np.testing.assert_allclose(out["approach"][0].numpy(), ref["approach"], atol=2e-3)
    np.testing.assert_allclose(out["closing"][0].numpy(), ref["closing"], atol=2e-3)


def test_interpolation_weights_the_nearest_points():
    rng = np.random.default_rng(1)
    pos = torch.from_numpy(rng.uniform(size=(1, 500, 3)).astype(np.float32))
    x = torch.from_numpy(rng.normal(size=(1, 500, 4)).astype(np.float32))
    torch.testing.assert_close(knn_interpolate(x, pos, pos[:, :30]), x[:, :30])


def test_pretrained_network_proposes_top_down_grasps_on_the_mug(policy, mug_obs):
    grasps = policy.plan(mug_obs, seed=0)
    assert len(grasps) >= 5, "the pretrained network finds grasps on a mug"
    scores = [g.score for g in grasps]
    assert scores == sorted(scores, reverse=True) and scores[0] > 0.5
    obj = mug_obs.points
    for g in grasps[:5]:
        rot = g.pose[:3, :3]
        np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-5)
        assert np.linalg.det(rot) > 0.99
        # the TCP lies on the object (within the hand's reach of its points), the approach comes from above
        assert np.linalg.norm(obj - g.pose[:3, 3], axis=1).min() < 0.03
        assert g.pose[2, 2] < 0.2
        assert 0.0 <= g.width <= 0.08


def test_seeded_inference_is_repeatable_and_batching_changes_nothing(policy, mug_obs):
    box = trimesh.creation.box((0.05, 0.06, 0.12))
    box_obs = scene_observation(box, seed=1)
    single = [policy.plan(mug_obs, seed=5), policy.plan(box_obs, seed=9)]
    again = policy.plan(mug_obs, seed=5)
    batched = policy.plan_batch([mug_obs, box_obs], [5, 9])
    for a, b in zip(single, batched, strict=True):
        assert len(a) == len(b) > 0
        np.testing.assert_allclose([g.pose for g in a], [g.pose for g in b], atol=1e-5)
    np.testing.assert_array_equal([g.pose for g in single[0]], [g.pose for g in again])


def test_an_object_out_of_view_gives_no_grasp_never_a_crash(policy, mug_obs):
    few = GraspObservation(points=mug_obs.points[:10], viewpoints=mug_obs.viewpoints[:10], table_z=0.0,
                           context=mug_obs.context)
    assert policy.plan(few, seed=0) == []
    empty = GraspObservation(points=np.zeros((0, 3)), viewpoints=np.zeros((0, 3)), table_z=0.0)
    assert policy.plan(empty, seed=0) == []


def test_missing_weights_say_how_to_install(monkeypatch):
    assert checkpoint_path().is_file()
    import importlib.util

    monkeypatch.setattr(importlib.util, "find_spec", lambda name: None)
    with pytest.raises(CGNWeightsError, match="pip install --no-deps cgn-pytorch"):
        ContactGraspNet.pretrained()


@pytest.mark.sim
@pytest.mark.slow
def test_in_the_simulator_batched_planning_gives_the_same_trials_as_one_by_one():
    import hydra
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from grt.tasks import get_task

    conf = __import__("pathlib").Path(__file__).parents[2] / "conf"
    with initialize_config_dir(str(conf / "task"), version_base="1.3"):
        cfg = compose("grasp_2cam")
    session_cfg = OmegaConf.to_container(cfg.session, resolve=False)
    session_cfg["env_id"] = cfg.env_id
    box = trimesh.creation.box((0.05, 0.06, 0.10))
    box.apply_translation([0.0, 0.0, 0.05])
    results = {}
    for batch in (1, 2):
        policy = ContactGraspNetPolicy(num_points=12000, batch_size=batch, max_retries=3)
        session = hydra.utils.instantiate(session_cfg, policy=policy, _convert_="all")
        try:
            session.load_object(box, [np.asarray(box.vertices)])
            session.prefetch([1, 2])
            results[batch] = [session.run_trial(s) for s in (1, 2)]
        finally:
            session.close()
    for one, two in zip(results[1], results[2], strict=True):
        assert one.mode in get_task("grasp").failure_modes and one.mode == two.mode
        assert two.info.get("batched") and not one.info.get("batched")
        np.testing.assert_allclose(one.info["object_final"], two.info["object_final"], atol=1e-5)
    assert any(o.success for o in results[1]), [o.mode for o in results[1]]


def test_grasps_on_a_wide_box_are_centered_between_the_fingers(policy):
    box = trimesh.creation.box((0.066, 0.066, 0.12))
    obs = scene_observation(box, seed=2)
    grasps = policy.plan(obs, seed=3)
    assert grasps, "a can-sized box is graspable across its 66 mm"
    assert all(0.0 < g.width <= 0.076 for g in grasps)
    # Face to face: the closing axis within 15 deg of a side's normal (the others pinch an edge or a corner).
    across = [(g, axis) for g in grasps for axis in (0, 1) if abs(g.pose[axis, 1]) > np.cos(np.deg2rad(15))]
    assert across
    for g, axis in across:
        # the fingers close symmetrically about the box: the TCP sits on its mid-plane, the width spans it
        assert abs(g.pose[axis, 3]) < 0.006
        assert g.width > 0.06
    raw = ContactGraspNetPolicy(num_points=12000, recenter=False, max_retries=2).plan(obs, seed=3)
    assert len(raw) < len(grasps)  # the predicted widths (~1 cm) put a finger inside the box
