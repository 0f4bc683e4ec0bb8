"""Antipodal grasp sampling on a point cloud for a parallel-jaw gripper (the Dex-Net / GPD family).

The paper's Contact-GraspNet is not available here; this predictor stands in for it as a real,
geometry-driven black box. One inference:

1. **Contact pairs.** Sample seed points; from each, walk into the object along its inward normal
   and take the first point whose outward normal points back along the walk (the exit surface)
   within a thin tube: a candidate pair ``(p, q)`` of width ``|q - p| <= max_width - width_margin``.
2. **Friction cones.** Keep the pair if the line ``p -> q`` lies inside both friction cones
   (half-angle ``atan(friction_coef)``): the Nguyen force-closure test for two soft contacts.
3. **Approach directions.** Closing axis y = ``(q - p)/|q - p|``; approach directions z sampled
   around y, starting at the most top-down one; directions more than ``max_approach_angle`` from
   straight down are dropped.
4. **Collision check.** Finger, palm and wrist boxes of the open Panda hand (and the 5 cm pre-grasp
   retreat) must hold no cloud point, every box corner must stay above the table, and each finger
   pad must touch at least one point.
5. **Ranking** by antipodality, approach from above and closeness of the grasp center to the
   cloud's centroid (a proxy for the center of mass: less torque while shaking).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from grt.policies.base import Grasp, GraspPredictor, PointCloudGraspPolicy
from grt.policies.pointcloud import voxel_representatives


@dataclass(frozen=True)
class HandGeometry:
    """Panda hand collision boxes in the TCP frame (z approach, y closing), meters.

    Measured from ManiSkill's Panda collision shapes: finger pads span z in [-0.009, 0.0095] and
    open to ``|y| = 0.04``; fingers reach back to z = -0.045; the palm starts at z = -0.037.
    """

    max_width: float = 0.08
    finger_depth_y: float = 0.026
    finger_half_x: float = 0.011
    finger_z: tuple[float, float] = (-0.045, 0.0095)
    pad_half_x: float = 0.0088
    pad_z: tuple[float, float] = (-0.009, 0.0095)
    palm_half_x: float = 0.032
    palm_half_y: float = 0.105
    palm_z: tuple[float, float] = (-0.2, -0.037)  # reaches back over the wrist and the 5 cm retreat


def find_contact_pairs(points: np.ndarray, normals: np.ndarray, seeds: np.ndarray, max_width: float,
                       min_width: float, tube_radius: float, cos_cone: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Pair each seed with the first exit point along its inward normal.

    Args:
        points: ``(P, 3)`` points (m).
        normals: ``(P, 3)`` unit outward normals.
        seeds: ``(M,)`` indices of seed points.
        max_width, min_width: range (m) of the contact distance.
        tube_radius: how far (m) from the seed's inward ray a partner may lie.
        cos_cone: cosine of the friction-cone half-angle.

    Returns:
        ``(K,)`` seed indices and ``(K,)`` partner indices of the pairs that passed both cones.
    """
    d = -normals[seeds]  # (M, 3) inward rays
    # Candidates: points in the ball that encloses the search tube of each ray (KD-tree, no M x P).
    mids = points[seeds] + 0.5 * max_width * d
    balls = cKDTree(points).query_ball_point(mids, r=float(np.hypot(0.5 * max_width, tube_radius)))
    counts = np.array([len(b) for b in balls])
    if counts.sum() == 0:
        return np.zeros(0, int), np.zeros(0, int)
    row = np.repeat(np.arange(len(seeds)), counts)
    cand = np.concatenate([np.asarray(b, int) for b in balls])
    vec = points[cand] - points[seeds][row]
    t = np.einsum("ki,ki->k", vec, d[row])
    radial = np.sqrt(np.maximum(np.einsum("ki,ki->k", vec, vec) - t * t, 0.0))
    ok = ((t > min_width) & (t < max_width) & (radial < tube_radius)
          & (np.einsum("ki,ki->k", normals[cand], d[row]) > cos_cone))
    row, cand, key = row[ok], cand[ok], (t + radial)[ok]
    # Per seed, the nearest exit surface; on it, the point nearest the ray.
    order = np.lexsort((key, row))
    first = order[np.r_[True, row[order][1:] != row[order][:-1]]] if len(order) else order
    i, j = seeds[row[first]], cand[first]
    u = points[j] - points[i]
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    cone_i = np.einsum("ki,ki->k", -normals[i], u) > cos_cone
    cone = cone_i & (np.einsum("ki,ki->k", normals[j], u) > cos_cone)
    return i[cone], j[cone]


def approach_frames(closing: np.ndarray, num_approaches: int, max_angle: float
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Rotations whose y axis is ``closing`` and whose z axis (approach) circles around it.

    Args:
        closing: ``(K, 3)`` unit closing axes.
        num_approaches: approach angles per axis, evenly spaced from the most top-down one.
        max_angle: largest angle (rad) between the approach and straight down (-z world).

    Returns:
        ``(N, 3, 3)`` rotations (columns x, y, z) and ``(N,)`` index of the pair each belongs to.
    """
    down = np.array([0.0, 0.0, -1.0])
    a = down - (closing @ down)[:, None] * closing
    degenerate = np.linalg.norm(a, axis=1) < 1e-3
    a[degenerate] = np.cross(closing[degenerate], [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(closing, a)
    phis = np.linspace(0.0, 2 * np.pi, num_approaches, endpoint=False)
    phis = np.where(phis > np.pi, phis - 2 * np.pi, phis)
    z = np.cos(phis)[None, :, None] * a[:, None] + np.sin(phis)[None, :, None] * b[:, None]  # (K, A, 3)
    y = np.broadcast_to(closing[:, None], z.shape)
    rot = np.stack([np.cross(y, z), y, z], axis=-1).reshape(-1, 3, 3)
    pair = np.repeat(np.arange(len(closing)), num_approaches)
    keep = rot[:, :, 2] @ down >= np.cos(max_angle) - 1e-9
    return rot[keep], pair[keep]


def hand_clearance(points: np.ndarray, rot: np.ndarray, tcp: np.ndarray, hand: HandGeometry,
                   table_z: float, margin: float, pad_points: np.ndarray | None = None) -> np.ndarray:
    """Which hand poses hold no cloud point in their boxes, stay above the table and touch with both pads.

    Args:
        points: ``(P, 3)`` cloud (m).
        rot: ``(N, 3, 3)`` TCP rotations; tcp: ``(N, 3)`` TCP positions (m).
        hand: hand geometry; table_z: table height (m); margin: clearance (m) added to every box.
        pad_points: the points the pads must touch (default: ``points``), e.g. the object's alone when
            ``points`` also holds the table.

    Returns:
        ``(N,)`` bool mask of the valid poses.
    """
    local = np.matmul(points[None], rot) - np.einsum("ni,nij->nj", tcp, rot)[:, None]  # (N, P, 3) R^T(p - t)
    x, y, z = np.abs(local[..., 0]), local[..., 1], local[..., 2]
    half = hand.max_width / 2
    in_finger = ((x < hand.finger_half_x + margin) & (np.abs(y) > half - margin)
                 & (np.abs(y) < half + hand.finger_depth_y + margin)
                 & (z > hand.finger_z[0] - margin) & (z < hand.finger_z[1] + margin))
    in_palm = ((x < hand.palm_half_x + margin) & (np.abs(y) < hand.palm_half_y + margin)
               & (z > hand.palm_z[0]) & (z < hand.palm_z[1] + margin))
    free = ~(in_finger | in_palm).any(axis=1)
    if pad_points is not None:
        local = np.matmul(pad_points[None], rot) - np.einsum("ni,nij->nj", tcp, rot)[:, None]
        x, y, z = np.abs(local[..., 0]), local[..., 1], local[..., 2]
    in_pad = (x < hand.pad_half_x) & (z > hand.pad_z[0]) & (z < hand.pad_z[1]) & (np.abs(y) < half)
    both_pads = (in_pad & (y > 0)).any(axis=1) & (in_pad & (y < 0)).any(axis=1)
    corners = np.array([[sx * hand.palm_half_x, sy * (half + hand.finger_depth_y), hand.finger_z[1]]
                        for sx in (-1, 1) for sy in (-1, 1)]
                       + [[sx * hand.palm_half_x, sy * hand.palm_half_y, hand.palm_z[1]]
                          for sx in (-1, 1) for sy in (-1, 1)])
    lowest = (np.einsum("nij,cj->nci", rot, corners) + tcp[:, None])[..., 2].min(axis=1)
    return free & both_pads & (lowest > table_z + margin)


class AntipodalGraspPredictor(GraspPredictor):
    """Antipodal sampling + friction cones + hand collision check + ranking (see module docstring).

    Args:
        num_samples: seed points per inference.
        num_approaches: approach directions per contact pair.
        friction_coef: friction coefficient of the cone test (half-angle ``atan(mu)``).
        width_margin: required clearance (m): contact width <= ``hand.max_width - width_margin``.
        min_width: thinnest graspable section (m).
        tube_radius: partner search radius (m) around the inward ray.
        max_approach_angle: largest tilt (rad) of the approach from straight down.
        grasp_depth: how far (m) the TCP goes past the contact center along the approach.
        collision_margin: clearance (m) added to the hand boxes.
        collision_voxel: voxel (m) of the cloud used for the hand collision check.
        max_grasps: grasps returned at most.
        weights: (antipodality, top-down, centering) score weights.
    """

    def __init__(self, num_samples: int = 256, num_approaches: int = 12, friction_coef: float = 0.4,
                 width_margin: float = 0.01, min_width: float = 0.003, tube_radius: float = 0.003,
                 max_approach_angle: float = 1.40, grasp_depth: float = 0.002,
                 collision_margin: float = 0.003, collision_voxel: float = 0.005, max_grasps: int = 32,
                 weights: tuple[float, float, float] = (1.0, 0.5, 1.0)):
        self.num_samples, self.num_approaches = int(num_samples), int(num_approaches)
        self.cos_cone = float(np.cos(np.arctan(friction_coef)))
        self.width_margin, self.min_width = float(width_margin), float(min_width)
        self.tube_radius = float(tube_radius)
        self.max_approach_angle, self.grasp_depth = float(max_approach_angle), float(grasp_depth)
        self.collision_margin, self.max_grasps = float(collision_margin), int(max_grasps)
        self.collision_voxel = float(collision_voxel)
        self.weights = tuple(float(w) for w in weights)
        self.hand = HandGeometry()

    def predict(self, points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
                table_z: float = 0.0) -> list[Grasp]:
        seeds = rng.choice(len(points), size=min(self.num_samples, len(points)), replace=False)
        i, j = find_contact_pairs(points, normals, seeds, self.hand.max_width - self.width_margin,
                                  self.min_width, self.tube_radius, self.cos_cone)
        if len(i) == 0:
            return []
        closing = points[j] - points[i]
        width = np.linalg.norm(closing, axis=1)
        closing /= width[:, None]
        rot, pair = approach_frames(closing, self.num_approaches, self.max_approach_angle)
        center = 0.5 * (points[i] + points[j])[pair]
        tcp = center + self.grasp_depth * rot[:, :, 2]
        scores, terms = self._scores(points, normals, i[pair], j[pair], rot, center)
        keep = self._collision_free_best(points, rot, tcp, np.argsort(-scores, kind="stable"), table_z)
        grasps = []
        for k in keep:
            info = {n: float(v[k]) for n, v in terms.items()}
            info["contacts"] = np.stack([points[i[pair[k]]], points[j[pair[k]]]])
            grasps.append(self._grasp(rot[k], tcp[k], width[pair[k]], scores[k], info))
        return grasps

    def _collision_free_best(self, points, rot, tcp, order, table_z) -> list[int]:
        """Check hand collisions in score order, stopping at ``max_grasps`` valid ones."""
        cloud = points[voxel_representatives(points, self.collision_voxel)]
        keep: list[int] = []
        for chunk in np.array_split(order, max(1, len(order) // 64)):
            ok = hand_clearance(cloud, rot[chunk], tcp[chunk], self.hand, table_z, self.collision_margin)
            keep.extend(chunk[ok].tolist())
            if len(keep) >= self.max_grasps:
                break
        return keep[: self.max_grasps]

    def _scores(self, points, normals, i, j, rot, center) -> tuple[np.ndarray, dict]:
        u = points[j] - points[i]
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        cos_a = np.minimum(np.einsum("ki,ki->k", -normals[i], u), np.einsum("ki,ki->k", normals[j], u))
        antipodal = (cos_a - self.cos_cone) / (1.0 - self.cos_cone)
        top = -rot[:, 2, 2]
        centroid = points.mean(axis=0)
        extent = np.linalg.norm(points - centroid, axis=1).max() + 1e-9
        centering = 1.0 - np.minimum(1.0, np.linalg.norm(center - centroid, axis=1) / extent)
        w = self.weights
        terms = dict(antipodality=antipodal, top_down=top, centering=centering)
        return w[0] * antipodal + w[1] * top + w[2] * centering, terms

    @staticmethod
    def _grasp(rot: np.ndarray, tcp: np.ndarray, width: float, score: float, info: dict) -> Grasp:
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rot, tcp
        return Grasp(pose=pose, width=float(width), score=float(score), info=info)


class AntipodalGraspPolicy(PointCloudGraspPolicy):
    """The built-in grasp planner: :class:`AntipodalGraspPredictor` behind :class:`PointCloudGraspPolicy`.

    Args:
        max_retries: inferences before ``no_grasp_found`` (the paper: 10).
        voxel_size: voxel (m) of the downsampled cloud.
        normal_neighbors: neighbors of the PCA normals.
        **predictor_kwargs: plain arguments of :class:`AntipodalGraspPredictor`.
    """

    def __init__(self, max_retries: int = 10, voxel_size: float = 0.004, normal_neighbors: int = 12,
                 **predictor_kwargs):
        super().__init__(AntipodalGraspPredictor(**predictor_kwargs), max_retries=max_retries,
                         voxel_size=voxel_size, normal_neighbors=normal_neighbors)
