"""Contact-GraspNet as a GRT grasp policy: the paper's learned grasp planner (Tables 1 and 2).

One trial (the paper's execution, appendix "Grasping Task"):

1. **Cloud.** The task's six depth cameras see the object (segmented) and, with ``context_radius > 0``,
   the table top around it. ``cloud: scene`` gives the network what it was trained on: a table-top
   scene in a z-up frame centered on its mean, ``num_points`` (20,000) points drawn from the fused
   views; ``cloud: object`` gives the segmented object alone (see ``conf/policy/contact_graspnet.yaml``
   for which works, measured). The draw is seeded by the trial seed.
2. **Inference** (:mod:`grt.policies.cgn_net`): a grasp per farthest-point sample (2,048), with a
   success confidence. Only contacts on the object count (the segmentation mask), above
   ``threshold`` (0.5, the package's default).
3. **Geometric consistency checks**: the grasp is centered on the object's extent between the fingers
   (``recenter``: the checkpoint's width head is barely trained, see the argument), that width fits the
   opened hand, the hand (fingers,
   palm, wrist and the 5 cm pre-grasp retreat) holds no point of the cloud and stays above the table,
   both finger pads have object points between them, and the approach does not come from under the
   table (:func:`grt.policies.antipodal.hand_clearance`).
4. **Retries**: nothing left -> infer again with the next farthest-point starts, up to ``max_retries``
   (10) times, then ``no_grasp_found``.
5. Grasps are ranked by confidence and handed to the task (IK, 5 cm pre-grasp along the approach,
   close, lift, shake). Contact-GraspNet's grasp frame has x along the closing direction; the Panda's
   TCP frame has y there: the hand is turned 90 deg about the approach axis (the paper's rotation).

Every random choice (point draw, farthest-point starts) comes from generators seeded by the trial
seed, so the common random numbers of the search hold and a batch of clouds gives each trial the
grasps it would get alone (:meth:`ContactGraspNetPolicy.plan_batch`).
"""

from __future__ import annotations

import numpy as np
import torch

from grt.policies.antipodal import HandGeometry, hand_clearance
from grt.policies.base import Grasp, GraspObservation, GraspPolicy
from grt.policies.cgn_net import ContactGraspNet, grasp_frames
from grt.policies.pointcloud import voxel_representatives

_NETS: dict[str, ContactGraspNet] = {}


def _network(device: str) -> ContactGraspNet:
    """One network per process and device (loading takes ~1 s)."""
    if device not in _NETS:
        _NETS[device] = ContactGraspNet.pretrained(device)
    return _NETS[device]


class ContactGraspNetPolicy(GraspPolicy):
    """The pretrained Contact-GraspNet behind :class:`GraspPolicy` (see the module docstring).

    Args:
        cloud: ``scene`` (object + table top, as trained) or ``object`` (the segmented object alone).
        context_radius: m around the object whose table points the task captures (``scene`` only).
        num_points: points per inference (the network was trained on 20,000).
        threshold: minimum success confidence (sigmoid of the logit).
        max_retries: inferences before ``no_grasp_found`` (the paper: 10).
        min_points: object points below which the object counts as out of view (``no_grasp_found``).
        gripper_depth: m from the hand's base to the fingertip center (Panda: 0.1034).
        max_grasps: grasps returned at most (best first).
        collision_margin, collision_voxel: clearance (m) and cloud voxel (m) of the hand check.
        recenter: center each grasp on the object's extent between the fingers (its width measured on
            the cloud) instead of trusting the predicted width, which this checkpoint barely learned
            (raw widths -39 to +24 mm on the 66 mm can).
        batch_size: clouds per inference when the task plans trials ahead (:meth:`plan_batch`).
        device: ``cpu`` or ``cuda``.
    """

    def __init__(self, cloud: str = "scene", context_radius: float = 0.25, num_points: int = 20000,
                 threshold: float = 0.5, max_retries: int = 10, min_points: int = 64,
                 gripper_depth: float = 0.1034, max_grasps: int = 32, collision_margin: float = 0.002,
                 collision_voxel: float = 0.005, recenter: bool = True, batch_size: int = 1, device: str = "cpu"):
        if cloud not in ("scene", "object"):
            raise ValueError(f"policy.cloud={cloud!r}: use 'scene' (object + table, as trained) or 'object'")
        self.cloud = cloud
        self.context_radius = float(context_radius) if cloud == "scene" else 0.0
        self.num_points, self.threshold = int(num_points), float(threshold)
        self.max_retries, self.min_points = int(max_retries), int(min_points)
        self.gripper_depth, self.max_grasps = float(gripper_depth), int(max_grasps)
        self.collision_margin, self.collision_voxel = float(collision_margin), float(collision_voxel)
        self.recenter = bool(recenter)
        self.batch_size, self.device = int(batch_size), str(device)
        self.hand = HandGeometry()
        self.net = _network(self.device)

    # --- GraspPolicy ------------------------------------------------------------------------------------
    def plan(self, obs: GraspObservation, seed: int) -> list[Grasp]:
        return self.plan_batch([obs], [seed])[0]

    def plan_batch(self, observations: list[GraspObservation], seeds: list[int]) -> list[list[Grasp]]:
        """Ranked grasps of several trials, their clouds inferred together (retries batched too)."""
        results: list[list[Grasp]] = [[] for _ in observations]
        inputs = {}
        for k, (obs, seed) in enumerate(zip(observations, seeds, strict=True)):
            if len(obs.points) >= self.min_points:
                inputs[k] = self._input(obs, int(seed))
        generators = {k: torch.Generator().manual_seed(int(seeds[k])) for k in inputs}
        pending = list(inputs)
        for attempt in range(self.max_retries):
            if not pending:
                break
            # Clouds of one size go through the network together.
            for group in _same_size(pending, inputs):
                pos = torch.from_numpy(np.stack([inputs[k][0] for k in group])).to(self.device)
                out = self.net(pos, [generators[k] for k in group], max_width=self.hand.max_width)
                for row, k in enumerate(group):
                    grasps = self._grasps({n: v[row] for n, v in out.items()}, observations[k], inputs[k], attempt)
                    if grasps:
                        results[k] = grasps
            pending = [k for k in pending if not results[k]]
        return results

    # --- steps --------------------------------------------------------------------------------------------
    def _input(self, obs: GraspObservation, seed: int):
        """``(N, 3)`` float32 centered cloud, its center (m, world), the object mask and the cloud (world)."""
        points = np.asarray(obs.points, np.float64)
        if self.cloud == "scene" and obs.context is not None and len(obs.context):
            points = np.concatenate([points, np.asarray(obs.context, np.float64)])
        is_object = np.arange(len(points)) < len(obs.points)
        rng = np.random.default_rng(seed)
        if len(points) > self.num_points:
            keep = np.sort(rng.choice(len(points), self.num_points, replace=False))
            points, is_object = points[keep], is_object[keep]
        elif len(points) < ContactGraspNet.CENTERS[0]:  # too few for 2,048 samples: repeat points
            extra = rng.choice(len(points), ContactGraspNet.CENTERS[0] - len(points), replace=True)
            points, is_object = np.concatenate([points, points[extra]]), np.concatenate([is_object, is_object[extra]])
        center = points.mean(axis=0)
        return (points - center).astype(np.float32), center, is_object, points

    def _grasps(self, out: dict, obs: GraspObservation, inp, attempt: int) -> list[Grasp]:
        _, center, is_object, cloud = inp
        conf = torch.sigmoid(out["logits"]).cpu().numpy()
        on_object = is_object[out["index"].cpu().numpy()]
        ok = on_object & (conf > self.threshold)
        if not ok.any():
            return []
        order = np.flatnonzero(ok)[np.argsort(-conf[ok], kind="stable")]
        frames = grasp_frames(out["points"][order], out["approach"][order], out["closing"][order],
                              out["width"][order], self.gripper_depth).cpu().numpy().astype(np.float64)
        frames[:, :3, 3] += center
        # Contact-GraspNet frame (x closing, z approach, origin at the hand base) -> TCP frame
        # (y closing, z approach, origin between the fingertips): 90 deg about z, then the depth.
        rot = np.stack([-frames[:, :3, 1], frames[:, :3, 0], frames[:, :3, 2]], axis=-1)
        tcp = frames[:, :3, 3] + self.gripper_depth * frames[:, :3, 2]
        width = out["width"][order].cpu().numpy()
        if self.recenter:
            tcp, width = self._recenter(obs, rot, tcp)
        checks = self._consistent(cloud, obs, rot, tcp, width)
        grasps = []
        for k in np.flatnonzero(checks)[: self.max_grasps]:
            pose = np.eye(4)
            pose[:3, :3], pose[:3, 3] = rot[k], tcp[k]
            grasps.append(Grasp(pose=pose, width=float(width[k]), score=float(conf[order[k]]),
                                info=dict(confidence=float(conf[order[k]]), attempt=attempt,
                                          contact=out["points"][order[k]].cpu().numpy() + center)))
        return grasps

    def _recenter(self, obs: GraspObservation, rot: np.ndarray, tcp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Center each grasp on the object's extent between the fingers; that extent is its width.

        The object points in the finger pads' window (across x, along the approach z) within one hand
        opening of the predicted center along the closing axis y give ``[y_min, y_max]``; the TCP moves to
        its middle. A grasp whose window holds no object point keeps its pose and gets width ``inf``
        (refused by the width check).
        """
        obj = np.asarray(obs.points, np.float64)
        if len(obj) == 0:
            return tcp, np.full(len(tcp), np.inf)
        obj = obj[voxel_representatives(obj, 0.5 * self.collision_voxel)]
        hand, out_tcp, out_w = self.hand, tcp.copy(), np.full(len(tcp), np.inf)
        for chunk in np.array_split(np.arange(len(rot)), max(1, len(rot) // 64)):
            if len(chunk) == 0:
                continue
            local = np.matmul(obj[None], rot[chunk]) - np.einsum("ni,nij->nj", tcp[chunk], rot[chunk])[:, None]
            x, y, z = np.abs(local[..., 0]), local[..., 1], local[..., 2]
            window = (x < hand.pad_half_x) & (z > hand.pad_z[0]) & (z < hand.pad_z[1]) & (np.abs(y) < hand.max_width)
            has = window.any(axis=1)
            lo = np.where(window, y, np.inf).min(axis=1)
            hi = np.where(window, y, -np.inf).max(axis=1)
            mid = np.where(has, 0.5 * (lo + hi), 0.0)
            out_tcp[chunk] = tcp[chunk] + mid[:, None] * rot[chunk][:, :, 1]
            out_w[chunk] = np.where(has, hi - lo, np.inf)
        return out_tcp, out_w

    def _consistent(self, cloud, obs: GraspObservation, rot, tcp, width) -> np.ndarray:
        """Geometric consistency: width fits, no cloud point in the hand, above the table, pads on the object."""
        fits = width <= self.hand.max_width - 2 * self.collision_margin
        pts = cloud[voxel_representatives(cloud, self.collision_voxel)]
        obj = np.asarray(obs.points, np.float64)
        obj = obj[voxel_representatives(obj, self.collision_voxel)] if len(obj) else obj
        ok = np.zeros(len(rot), bool)
        for chunk in np.array_split(np.arange(len(rot)), max(1, len(rot) // 64)):
            if len(chunk) == 0:
                continue
            # Hand boxes free of every point (object and table); pads on the object's own points.
            free = hand_clearance(pts, rot[chunk], tcp[chunk], self.hand, obs.table_z, self.collision_margin,
                                  pad_points=obj)
            ok[chunk] = free & fits[chunk]
            if ok.sum() >= self.max_grasps:
                break
        return ok


def _same_size(keys: list[int], inputs: dict) -> list[list[int]]:
    groups: dict[int, list[int]] = {}
    for k in keys:
        groups.setdefault(len(inputs[k][0]), []).append(k)
    return list(groups.values())
