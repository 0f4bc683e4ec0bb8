"""Unit tests of the antipodal grasp sampler on synthetic clouds (no simulator)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from omegaconf import OmegaConf

from grt.policies.antipodal import (
    AntipodalGraspPolicy,
    AntipodalGraspPredictor,
    HandGeometry,
    approach_frames,
    find_contact_pairs,
    hand_clearance,
)
from grt.policies.base import Grasp, GraspObservation, GraspPredictor, PointCloudGraspPolicy
from grt.policies.pointcloud import estimate_normals, voxel_downsample


def surface_cloud(mesh: trimesh.Trimesh, count: int = 6000, seed: int = 0) -> GraspObservation:
    """Surface points (no occlusion) seen by the one of six hemisphere cameras that faces each best."""
    points, faces = trimesh.sample.sample_surface(mesh, count * 2, seed=seed)
    normals = mesh.face_normals[faces]
    az = np.deg2rad(30.0 + 60.0 * np.arange(6))
    cams = 0.55 * np.c_[np.cos(az) * 0.7, np.sin(az) * 0.7, np.full(6, 0.7)] + [0.0, 0.0, 0.05]
    rays = cams[None] - points[:, None]
    facing = np.einsum("pci,pi->pc", rays / np.linalg.norm(rays, axis=-1, keepdims=True), normals)
    best = facing.argmax(axis=1)
    keep = facing.max(axis=1) > 0.05
    return GraspObservation(points=points[keep][:count], viewpoints=cams[best][keep][:count], table_z=0.0)


def standing_box(extents=(0.05, 0.05, 0.10)) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents)
    mesh.apply_translation([0.0, 0.0, extents[2] / 2])
    return mesh


def test_normals_point_to_the_camera(rng):
    points = np.c_[rng.uniform(-0.05, 0.05, (500, 2)), np.zeros(500)]
    normals = estimate_normals(points, np.tile([0.0, 0.0, 1.0], (500, 1)), k=10)
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, 1.0], (500, 1)), atol=1e-6)


def test_voxel_downsample_keeps_one_point_per_voxel(rng):
    points = rng.uniform(0.0, 0.01, (2000, 3))
    kept, views = voxel_downsample(points, points.copy(), 0.005)
    assert len(kept) == 8 and np.array_equal(kept, views)


def test_box_gives_top_down_grasps_across_its_width():
    obs = surface_cloud(standing_box())
    grasps = AntipodalGraspPolicy().plan(obs, seed=0)
    assert grasps, "a 5 cm box must be graspable"
    scores = [g.score for g in grasps]
    assert scores == sorted(scores, reverse=True)
    best = grasps[0]
    rot = best.pose[:3, :3]
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-9)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    assert rot[2, 2] < -0.9, "the best grasp comes from above"
    assert abs(rot[2, 1]) < 0.2, "the closing axis is horizontal"
    assert best.width == pytest.approx(0.05, abs=0.004)
    assert best.pose[2, 3] > 0.10 - HandGeometry().pad_z[1] - 0.04, "fingers stay above the table"


def test_object_wider_than_the_gripper_has_no_grasp():
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.07)
    sphere.apply_translation([0.0, 0.0, 0.07])
    assert AntipodalGraspPolicy(max_retries=3).plan(surface_cloud(sphere), seed=0) == []


def test_plan_is_deterministic_given_the_seed():
    obs = surface_cloud(standing_box((0.04, 0.06, 0.08)))
    policy = AntipodalGraspPolicy()
    a, b = policy.plan(obs, seed=7), policy.plan(obs, seed=7)
    assert len(a) == len(b) > 0
    for ga, gb in zip(a, b, strict=True):
        np.testing.assert_array_equal(ga.pose, gb.pose)


def test_friction_cone_rejects_a_wedge():
    # Two planes meeting at 90 deg: no pair of points has opposite normals.
    u = np.linspace(0.0, 0.03, 20)
    a = np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)
    left = np.c_[np.zeros(len(a)), a]
    right = np.c_[a[:, 0], np.zeros(len(a)), a[:, 1]]
    points = np.r_[left, right]
    normals = np.r_[np.tile([-1.0, 0, 0], (len(a), 1)), np.tile([0, -1.0, 0], (len(a), 1))]
    i, _ = find_contact_pairs(points, normals, np.arange(len(points)), 0.07, 0.003, 0.003,
                              np.cos(np.arctan(0.4)))
    assert len(i) == 0


def test_parallel_plates_pair_at_their_distance():
    u = np.linspace(-0.01, 0.01, 9)
    grid = np.stack(np.meshgrid(u, u), -1).reshape(-1, 2)
    points = np.r_[np.c_[np.full(len(grid), -0.015), grid], np.c_[np.full(len(grid), 0.015), grid]]
    normals = np.r_[np.tile([-1.0, 0, 0], (len(grid), 1)), np.tile([1.0, 0, 0], (len(grid), 1))]
    i, j = find_contact_pairs(points, normals, np.arange(len(points)), 0.07, 0.003, 0.003, 0.9)
    assert len(i) == len(points)
    np.testing.assert_allclose(np.linalg.norm(points[j] - points[i], axis=1), 0.03)


def test_approach_frames_are_rotations_with_the_given_closing_axis():
    closing = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    rot, pair = approach_frames(closing, 8, np.pi)
    assert len(rot) == 16 and set(pair) == {0, 1}
    np.testing.assert_allclose(np.einsum("nji,njk->nik", rot, rot), np.tile(np.eye(3), (16, 1, 1)), atol=1e-9)
    np.testing.assert_allclose(rot[:, :, 1], closing[pair])


def test_hand_clearance_sees_palm_and_table():
    hand = HandGeometry()
    top_down = np.diag([1.0, -1.0, -1.0])[None]  # z (approach) points down
    pads = np.array([[0.0, 0.02, 0.1], [0.0, -0.02, 0.1]])
    tcp = np.array([[0.0, 0.0, 0.1]])
    assert hand_clearance(pads, top_down, tcp, hand, 0.0, 0.003).all()
    in_palm = np.r_[pads, [[0.0, 0.0, 0.1 + 0.06]]]
    assert not hand_clearance(in_palm, top_down, tcp, hand, 0.0, 0.003).any()
    assert not hand_clearance(pads, top_down, tcp, hand, 0.095, 0.003).any(), "fingertips in the table"


class _FlakyPredictor(GraspPredictor):
    """A user predictor that finds nothing the first ``fails`` times."""

    def __init__(self, fails: int):
        self.fails, self.calls = fails, 0

    def predict(self, points, normals, rng, table_z=0.0):
        self.calls += 1
        if self.calls <= self.fails:
            return []
        return [Grasp(pose=np.eye(4), width=0.03, score=1.0)]


def test_user_predictor_is_retried():
    obs = surface_cloud(standing_box(), count=500)
    grasps = PointCloudGraspPolicy(_FlakyPredictor(3), max_retries=10).plan(obs, seed=0)
    assert len(grasps) == 1 and grasps[0].info["attempt"] == 3
    assert PointCloudGraspPolicy(_FlakyPredictor(99), max_retries=4).plan(obs, seed=0) == []


def test_predictor_defaults_match_the_policy_config():
    cfg = OmegaConf.load(Path(__file__).parents[2] / "conf" / "policy" / "antipodal.yaml")
    kwargs = {k: v for k, v in OmegaConf.to_container(cfg).items() if k != "_target_"}
    AntipodalGraspPolicy(**kwargs)  # every key is a real argument
    assert isinstance(AntipodalGraspPolicy().predictor, AntipodalGraspPredictor)
