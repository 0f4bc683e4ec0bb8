"""Record the reference outputs GRT's Contact-GraspNet is tested against (tests/data/cgn/reference.npz).

Needs what GRT itself avoids: ``torch-geometric==2.4.0`` and a compiled ``torch-cluster==1.6.3`` (a 10-20
minute source build against torch 2.13 on 2 cores), installed into a side folder, e.g.::

    .venv/bin/pip wheel torch-cluster==1.6.3 --no-deps --no-build-isolation -w /tmp/wheels
    .venv/bin/pip install --no-deps --target /tmp/cgn_ref /tmp/wheels/torch_cluster-*.whl torch-geometric==2.4.0
    .venv/bin/python scripts/cgn_reference.py /tmp/cgn_ref tests/data/cgn/reference.npz

It runs cgn-pytorch's own ``CGN`` class (its modules import ``meshcat`` for visualization only, which is
replaced by empty modules here) with torch-cluster's farthest-point sampling from index 0, on a
6,000-point table-top scene of the built-in mug, and torch-cluster's ``radius`` on 800 random points.
"""

from __future__ import annotations

import sys
import types
from pathlib import Path

import numpy as np
import torch


def scene_cloud(count: int, seed: int = 0) -> np.ndarray:
    """The mug standing on a table-top disc (25 cm), surface points, centered: the input the network expects."""
    import trimesh

    from grt.objects import get_object

    rng = np.random.default_rng(seed)
    mesh = get_object("mug")
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    obj = trimesh.sample.sample_surface(mesh, count // 10, seed=seed)[0]
    disc = rng.uniform(-0.25, 0.25, (count * 2, 2))
    disc = disc[np.linalg.norm(disc, axis=1) < 0.25][: count - len(obj)]
    cloud = np.concatenate([obj, np.c_[disc, np.zeros(len(disc))]])
    return (cloud - cloud.mean(axis=0)).astype(np.float32)


def main(ref_dir: str, out: str) -> None:
    sys.path.insert(0, ref_dir)
    for name in ("meshcat", "meshcat.geometry", "meshcat.transformations"):
        sys.modules[name] = types.ModuleType(name)
    import cgn_pytorch.contact_graspnet as cgn
    import cgn_pytorch.pointnet2 as pointnet2
    import torch_cluster
    from cgn_pytorch.util import config_utils

    from grt.policies.cgn_net import checkpoint_path

    fps = pointnet2.fps
    pointnet2.fps = lambda pos, batch, ratio: fps(pos, batch, ratio=ratio, random_start=False)
    net = cgn.CGN(config_utils.load_config(), "cpu")
    net.load_state_dict(torch.load(checkpoint_path(), map_location="cpu", weights_only=True)["state_dict"])
    net.eval()
    cloud = scene_cloud(6000)
    pos, batch = torch.from_numpy(cloud), torch.zeros(len(cloud), dtype=torch.long)
    idx = torch_cluster.fps(pos, batch, 2048 / len(pos), random_start=False)[:2048]
    with torch.no_grad():
        _, grasps, logits, _, _, _ = net(pos[:, 3:], pcd_poses=pos, batch=batch, idxs=idx, gripper_depth=0.1034,
                                         gripper_width=0.16)
    small = np.random.default_rng(0).uniform(-0.1, 0.1, (800, 3)).astype(np.float32)
    sp, sb = torch.from_numpy(small), torch.zeros(800, dtype=torch.long)
    row, col = torch_cluster.radius(sp, sp[:50], 0.05, sb, sb[:50], max_num_neighbors=16)
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, cloud=cloud, fps=idx.numpy(), logits=logits.reshape(-1).numpy().astype(np.float32),
                        approach=grasps[0, :, :3, 2].numpy().astype(np.float32),
                        closing=grasps[0, :, :3, 0].numpy().astype(np.float32),
                        small=small, radius_row=row.numpy(), radius_col=col.numpy())
    print(f"wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python scripts/cgn_reference.py REFERENCE_PACKAGES_DIR OUT.npz")
    main(sys.argv[1], sys.argv[2])
