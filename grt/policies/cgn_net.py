"""Contact-GraspNet's network in plain PyTorch, with the pretrained weights of the ``cgn-pytorch`` wheel.

The PyPI package ``cgn-pytorch`` (0.4.3, MIT) ships a PyTorch port of Contact-GraspNet (Sundermeyer et
al., ICRA 2021) and its trained weights (``cgn_pytorch/checkpoints/current.pth``). Its own modules cannot
be imported here: they import ``meshcat`` (and its IPython stack) at import time and call
``torch_geometric`` ops that need the compiled ``torch-cluster`` (a 10-20 minute source build on two cores,
and no wheel for this torch on the registry). This module is the one adapter: the same architecture
(PointNet++ multi-scale set abstraction, feature propagation, four 1x1-conv heads), with the module names
of the checkpoint so that ``load_state_dict(strict=True)`` takes the trained weights unchanged, and its
own torch implementations of the three graph ops the network calls:

- :func:`farthest_point_sampling` (torch-cluster ``fps``): the same greedy algorithm; the random start
  comes from a seeded ``torch.Generator`` (torch-cluster calls C ``rand()``, which cannot be seeded per
  trial), so an inference is a function of (cloud, seed).
- :func:`ball_queries` (torch-cluster ``radius``, ``max_num_neighbors=64``): a ball keeps the first 64
  points an unsorted nanoflann radius search finds, and nearly every ball of a 20,000-point scene holds
  more (1,890 of 2,048 at 2 cm). Which 64 is fixed by the k-d tree (middle split, leaf size 10) and its
  depth-first order: :class:`KDTreeOrder` builds the same tree and finds the same 64, vectorized. The
  nearest 64 instead change the network's outputs completely (confidence off by 0.13-0.39 on average,
  no overlap among the top 50 grasps); with the tree order they match the reference exactly.
- :func:`knn_interpolate` (torch-geometric's, over torch-cluster ``knn``): inverse squared distance
  weights over the 3 nearest points.

``PointNetConv`` (torch-geometric, ``add_self_loops=True``, max aggregation) is reproduced with its
quirk: after removing "self loops" it adds the edge from source point ``m`` to center ``m`` (indices of
two different sets). The weights were trained with it, so it stays; it is applied per cloud, so a
batch of clouds gives each cloud the result it would get alone.

Checked against the reference (cgn-pytorch's own ``CGN`` on torch-geometric 2.4.0 and a compiled
torch-cluster 1.6.3, the same farthest-point start): identical confidences and grasp axes on four scene
clouds; ``tests/data/cgn/reference.npz`` (``scripts/cgn_reference.py``) keeps one for the tests.

Frames: the network was trained on single-view scene clouds (objects and table) turned into a z-up
world frame and centered on their mean, 20,000 points. Grasps come back in the same frame as the
input: the hand's base frame, z the approach, x the closing direction, the fingertips ``gripper_depth``
(0.1034 m) along z.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from grt.errors import UserError

NUM_NEIGHBORS = 64  # max_num_neighbors of every ball in the checkpoint's set abstraction
INSTALL_HINT = ("python -m grt.setup cgn installs them (pip install --no-deps cgn-pytorch==0.4.3: the wheel holds "
                "the weights)")


class CGNWeightsError(UserError, RuntimeError):  # RuntimeError: what caught it before still does
    """The pretrained Contact-GraspNet weights are not installed."""


def checkpoint_path() -> Path:
    """Where the ``cgn-pytorch`` wheel keeps its weights (found without importing the package)."""
    spec = importlib.util.find_spec("cgn_pytorch")
    if spec is None or not spec.submodule_search_locations:
        raise CGNWeightsError(f"Contact-GraspNet is not installed: {INSTALL_HINT}")
    path = Path(list(spec.submodule_search_locations)[0]) / "checkpoints" / "current.pth"
    if not path.is_file():
        raise CGNWeightsError(f"Contact-GraspNet weights missing ({path}): {INSTALL_HINT}")
    return path


# --- graph ops ----------------------------------------------------------------------------------------
def farthest_point_sampling(pos: torch.Tensor, num: int, generators: list[torch.Generator] | None = None
                            ) -> torch.Tensor:
    """Greedy farthest-point sampling of ``num`` indices per cloud.

    Args:
        pos: ``(B, N, 3)`` points.
        num: samples per cloud (``<= N``).
        generators: one per cloud, draws its random start; ``None`` starts at index 0.

    Returns:
        ``(B, num)`` long indices into ``N``.
    """
    b, n, _ = pos.shape
    start = (torch.zeros(b, dtype=torch.long) if generators is None
             else torch.cat([torch.randint(n, (1,), generator=g) for g in generators]))
    # NumPy on three contiguous coordinate rows: ~15x faster than torch's per-op overhead on 2 cores.
    xyz = pos.detach().to("cpu", torch.float32).numpy().transpose(0, 2, 1).copy()  # (B, 3, N)
    rows = np.arange(b)
    out = np.empty((b, num), np.int64)
    far = start.numpy().copy()
    dist = np.full((b, n), np.inf, np.float32)
    step, tmp = np.empty((b, n), np.float32), np.empty((b, n), np.float32)
    for i in range(num):
        out[:, i] = far
        p = xyz[rows, :, far]  # (B, 3)
        np.subtract(xyz[:, 0], p[:, :1], out=step)
        np.multiply(step, step, out=step)
        for c in (1, 2):
            np.subtract(xyz[:, c], p[:, c:c + 1], out=tmp)
            np.multiply(tmp, tmp, out=tmp)
            np.add(step, tmp, out=step)
        np.minimum(dist, step, out=dist)
        far = dist.argmax(axis=1)
    return torch.from_numpy(out).to(pos.device)


def _gather(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``values[b, index[b, ...]]`` for ``values (B, N, C)`` and ``index (B, ...)``."""
    b = values.shape[0]
    flat = index.reshape(b, -1)
    out = torch.gather(values, 1, flat[..., None].expand(-1, -1, values.shape[-1]))
    return out.reshape(*index.shape, values.shape[-1])


LEAF_MAX = 10
_EPS = np.float32(1e-5)


class KDTreeOrder:
    """nanoflann's KDTreeSingleIndexAdaptor (middle split, leaf size 10) built like torch-cluster builds it.

    Only what fixes the order of a radius search is kept: per node the split feature, ``divlow`` and
    ``divhigh`` (tight bounds of the two children), the children, and the range of the permuted index
    array (``vind``) each subtree covers (a subtree is a contiguous range of it).
    """

    def __init__(self, points: np.ndarray):
        self.p = np.ascontiguousarray(points, np.float32)
        n = len(self.p)
        self.vind = np.arange(n)
        self.feat, self.divlow, self.divhigh, self.c1, self.c2, self.lo, self.hi = ([] for _ in range(7))
        bbox = np.stack([self.p.min(0), self.p.max(0)], axis=1)  # (3, 2) low, high
        self._build(0, n, bbox)
        self.feat, self.c1, self.c2 = (np.asarray(a, np.int64) for a in (self.feat, self.c1, self.c2))
        self.divlow, self.divhigh = np.asarray(self.divlow, np.float32), np.asarray(self.divhigh, np.float32)
        self.lo, self.hi = np.asarray(self.lo, np.int64), np.asarray(self.hi, np.int64)
        self.leaf = self.c1 < 0

    def _new(self, lo, hi) -> int:
        for a, v in ((self.feat, 0), (self.divlow, 0.0), (self.divhigh, 0.0), (self.c1, -1), (self.c2, -1),
                     (self.lo, lo), (self.hi, hi)):
            a.append(v)
        return len(self.feat) - 1

    def _build(self, left: int, right: int, bbox: np.ndarray) -> int:
        node = self._new(left, right)
        ind = self.vind[left:right]
        if right - left <= LEAF_MAX:
            pts = self.p[ind]
            bbox[:, 0], bbox[:, 1] = pts.min(0), pts.max(0)
            return node
        span = bbox[:, 1] - bbox[:, 0]
        max_span = span.max()
        cutfeat, max_spread = 0, np.float32(-1)
        for i in range(3):
            if span[i] > (np.float32(1) - _EPS) * max_span:
                v = self.p[ind, i]
                spread = v.max() - v.min()
                if spread > max_spread:
                    cutfeat, max_spread = i, spread
        split = (bbox[cutfeat, 0] + bbox[cutfeat, 1]) / np.float32(2)
        v = self.p[ind, cutfeat]
        lo_v, hi_v = v.min(), v.max()
        cut = lo_v if split < lo_v else (hi_v if split > hi_v else split)
        lim1, lim2 = _plane_split(ind, v, cut)
        count = right - left
        index = lim1 if lim1 > count // 2 else (lim2 if lim2 < count // 2 else count // 2)
        lb = bbox.copy()
        lb[cutfeat, 1] = cut
        c1 = self._build(left, left + index, lb)
        rb = bbox.copy()
        rb[cutfeat, 0] = cut
        c2 = self._build(left + index, right, rb)
        self.feat[node], self.c1[node], self.c2[node] = cutfeat, c1, c2
        self.divlow[node], self.divhigh[node] = lb[cutfeat, 1], rb[cutfeat, 0]
        bbox[:, 0] = np.minimum(lb[:, 0], rb[:, 0])
        bbox[:, 1] = np.maximum(lb[:, 1], rb[:, 1])
        return node

    def first_in_ball(self, queries: np.ndarray, radii: tuple[float, ...], k: int, chunk: int = 256
                      ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per radius, the first ``k`` points within it of each query in the k-d tree's search order:
        the neighbors torch-cluster's ``radius(..., max_num_neighbors=k)`` keeps on the CPU.

        Returns, per radius, ``(M, k)`` point indices and the mask of the filled slots.
        """
        q = np.ascontiguousarray(queries, np.float32)
        pv = self.p[self.vind]  # points in tree order
        outs = [(np.zeros((len(q), k), np.int64), np.zeros((len(q), k), bool)) for _ in radii]
        for s in range(0, len(q), chunk):
            qc = q[s:s + chunk]
            # nanoflann's squared L2 in float32, summed x, y, z in that order; a point is in if d < r^2.
            d = (qc[:, None, 0] - pv[None, :, 0]) ** 2
            d += (qc[:, None, 1] - pv[None, :, 1]) ** 2
            d += (qc[:, None, 2] - pv[None, :, 2]) ** 2
            cs = np.zeros((len(qc), len(pv) + 1), np.int32)
            for (out, valid), r in zip(outs, radii, strict=True):
                inball = d < np.float32(r) * np.float32(r)
                np.cumsum(inball, axis=1, out=cs[:, 1:])
                pos, ok = self._descend(qc, cs, np.nonzero(inball)[1], k)
                out[s:s + chunk] = self.vind[pos]
                valid[s:s + chunk] = ok
        return outs

    def _descend(self, q: np.ndarray, cs: np.ndarray, cols: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Walk each query's tree in nanoflann's order; ``cs`` counts its in-ball points along the tree order,
        ``cols`` lists their tree positions (row after row)."""
        m = len(q)
        rows = np.arange(m)
        node = np.zeros(m, np.int64)
        need = np.minimum(cs[:, -1], k).astype(np.int64)
        starts, lengths = [], []  # slices of each query's in-ball points, in tree order
        active = (need > 0) & ~self.leaf[node]
        while active.any():
            a = rows[active]
            n = node[a]
            val = q[a, self.feat[n]]
            left_first = (val - self.divlow[n]) + (val - self.divhigh[n]) < 0
            first = np.where(left_first, self.c1[n], self.c2[n])
            other = np.where(left_first, self.c2[n], self.c1[n])
            cnt = cs[a, self.hi[first]] - cs[a, self.lo[first]]
            take = cnt < need[a]
            t = a[take]
            starts.append((t, cs[t, self.lo[first[take]]]))
            lengths.append(cnt[take])
            need[t] -= cnt[take]
            node[a] = np.where(take, other, first)
            active = (need > 0) & ~self.leaf[node]
        t = rows[need > 0]
        starts.append((t, cs[t, self.lo[node[t]]]))
        lengths.append(need[t])
        # Expand (query, rank start, length) into in-ball ranks, then ranks into tree positions.
        qs = np.concatenate([s[0] for s in starts])
        first_rank = np.concatenate([s[1] for s in starts]).astype(np.int64)
        ln = np.concatenate(lengths).astype(np.int64)
        rep_q = np.repeat(qs, ln)
        offs = np.arange(ln.sum()) - np.repeat(np.cumsum(ln) - ln, ln)
        ranks = np.repeat(first_rank, ln) + offs
        # The (rank+1)-th in-ball point of query r is entry rank of r's run in ``cols``.
        row_start = np.concatenate([[0], np.cumsum(cs[:, -1].astype(np.int64))[:-1]])
        pos = cols[row_start[rep_q] + ranks]
        out = np.zeros((m, k), np.int64)
        ok = np.zeros((m, k), bool)
        order = np.argsort(rep_q, kind="stable")
        rq, rp = rep_q[order], pos[order]
        counts = np.bincount(rq, minlength=m)
        slot = np.arange(len(rq)) - np.repeat(np.cumsum(counts) - counts, counts)
        out[rq, slot] = rp
        ok[rq, slot] = True
        return out, ok


def _plane_split(ind: np.ndarray, v: np.ndarray, cut) -> tuple[int, int]:
    """nanoflann's planeSplit (two Hoare passes: < cut, == cut, > cut), in place on ``ind`` and ``v``."""
    a = np.flatnonzero(v >= cut)
    b = np.flatnonzero(v < cut)[::-1]
    n = min(len(a), len(b))
    sw = int(np.count_nonzero(a[:n] < b[:n]))
    _swap(ind, v, a[:sw], b[:sw])
    lim1 = int(np.count_nonzero(v < cut))
    rest = np.arange(lim1, len(v))
    a = rest[v[lim1:] > cut]
    b = rest[v[lim1:] <= cut][::-1]
    n = min(len(a), len(b))
    sw = int(np.count_nonzero(a[:n] < b[:n]))
    _swap(ind, v, a[:sw], b[:sw])
    lim2 = lim1 + int(np.count_nonzero(v[lim1:] <= cut))
    return lim1, lim2


def _swap(ind, v, i, j):
    ind[i], ind[j] = ind[j].copy(), ind[i].copy()
    v[i], v[j] = v[j].copy(), v[i].copy()


def ball_queries(pos: torch.Tensor, centers_idx: torch.Tensor, radii: tuple[float, ...],
                 k: int = NUM_NEIGHBORS) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """torch-cluster's ``radius`` neighbors (``max_num_neighbors=k``) of the centers, one k-d tree per cloud.

    Returns, per radius, ``(B, M, k)`` indices into ``N`` and the ``(B, M, k)`` mask of the filled slots.
    """
    p = pos.detach().cpu().numpy()
    c = centers_idx.detach().cpu().numpy()
    per_cloud = [KDTreeOrder(p[b]).first_in_ball(p[b][c[b]], radii, k) for b in range(len(p))]
    return [(torch.from_numpy(np.stack([cl[i][0] for cl in per_cloud])).to(pos.device),
             torch.from_numpy(np.stack([cl[i][1] for cl in per_cloud])).to(pos.device)) for i in range(len(radii))]


def knn_interpolate(x: torch.Tensor, pos: torch.Tensor, pos_to: torch.Tensor, k: int = 3) -> torch.Tensor:
    """Features at ``pos_to`` by inverse-squared-distance weighting of the ``k`` nearest ``pos``.

    Args:
        x: ``(B, N, C)`` features at ``pos (B, N, 3)``; pos_to: ``(B, M, 3)``.

    Returns:
        ``(B, M, C)``.
    """
    k = min(k, pos.shape[1])
    p, q = pos.detach().cpu().numpy(), pos_to.detach().cpu().numpy()
    idx = np.empty((*q.shape[:2], k), np.int64)
    for b in range(p.shape[0]):
        idx[b] = np.asarray(cKDTree(p[b]).query(q[b], k=k)[1]).reshape(q.shape[1], k)
    nearest = torch.from_numpy(idx).to(pos.device)
    d2 = ((_gather(pos, nearest) - pos_to[:, :, None]) ** 2).sum(-1)
    w = 1.0 / d2.clamp(min=1e-16)
    return (_gather(x, nearest) * w[..., None]).sum(2) / w.sum(2, keepdim=True)


# --- modules (names follow the checkpoint) --------------------------------------------------------------
def mlp(channels: list[int]) -> nn.Sequential:
    """torch-geometric's PointNet++ MLP: (Linear, ReLU, BatchNorm) per layer."""
    return nn.Sequential(*[nn.Sequential(nn.Linear(channels[i - 1], channels[i]), nn.ReLU(),
                                         nn.BatchNorm1d(channels[i])) for i in range(1, len(channels))])


def _apply_mlp(net: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    shape = x.shape
    return net(x.reshape(-1, shape[-1])).reshape(*shape[:-1], -1)


class _PointConv(nn.Module):
    def __init__(self, local_nn: nn.Sequential):
        super().__init__()
        self.local_nn = local_nn


class SetAbstraction(nn.Module):
    """One PointNet++ scale: max over the MLP of (feature, offset) of each center's ball."""

    def __init__(self, radius: float, channels: list[int]):
        super().__init__()
        self.r = float(radius)
        self.conv = _PointConv(mlp(channels))

    def forward(self, x: torch.Tensor, pos: torch.Tensor, centers_idx: torch.Tensor, nbr: torch.Tensor,
                valid: torch.Tensor) -> torch.Tensor:
        """``x (B, N, C)`` at ``pos (B, N, 3)``, centers ``pos[centers_idx] (B, M)``, their neighbors
        ``nbr (B, M, 64)`` (``valid`` slots) -> ``(B, M, C')``."""
        centers = _gather(pos, centers_idx)
        m = centers_idx.shape[1]
        # torch-geometric's PointNetConv "self loop" on a bipartite graph: source m -> center m.
        loop = torch.arange(m, device=pos.device).clamp(max=pos.shape[1] - 1)
        nbr = torch.cat([nbr, loop.expand(nbr.shape[0], m)[..., None]], dim=2)
        valid = torch.cat([valid, torch.ones_like(valid[..., :1])], dim=2)
        # Only the real edges go through the MLP (balls on a sparse table hold few points), then a max
        # per center.
        bi, mi, si = valid.nonzero(as_tuple=True)
        src = nbr[bi, mi, si]
        msg = pos[bi, src] - centers[bi, mi]
        if x.shape[-1]:
            msg = torch.cat([x[bi, src], msg], dim=-1)
        out = self.conv.local_nn(msg)
        dst = bi * m + mi
        pooled = out.new_full((nbr.shape[0] * m, out.shape[-1]), float("-inf"))
        pooled = pooled.scatter_reduce(0, dst[:, None].expand_as(out), out, reduce="amax", include_self=True)
        return pooled.reshape(nbr.shape[0], m, -1)


class FeaturePropagation(nn.Module):
    def __init__(self, channels: list[int], k: int = 3):
        super().__init__()
        self.k = k
        self.nn = mlp(channels)

    def forward(self, x, pos, x_skip, pos_skip):
        y = knn_interpolate(x, pos, pos_skip, self.k)
        if x_skip is not None and x_skip.shape[-1]:
            y = torch.cat([y, x_skip], dim=-1)
        return _apply_mlp(self.nn, y)


class ContactGraspNet(nn.Module):
    """The checkpoint's network (config of ``cgn_pytorch/checkpoints/config.yaml``).

    Levels: 2048 centers (radii 0.02/0.04/0.08 m), 512 (0.04/0.08/0.16), 128 (0.08/0.16/0.32); three
    feature propagations back to the 2048 centers; heads: success logit, two direction vectors, width.
    """

    RADII = ((0.02, 0.04, 0.08), (0.04, 0.08, 0.16), (0.08, 0.16, 0.32))
    CENTERS = (2048, 512, 128)
    MLPS = (((32, 32, 64), (64, 64, 128), (64, 96, 128)),
            ((64, 64, 128), (128, 128, 256), (128, 128, 256)),
            ((64, 64, 128), (128, 128, 256), (128, 128, 256)))

    def __init__(self):
        super().__init__()
        levels, in_dim, cat_dims = [], 0, []
        for radii, mlps in zip(self.RADII, self.MLPS, strict=True):
            levels.append(nn.ModuleList([SetAbstraction(r, [in_dim + 3, *ch]) for r, ch in zip(radii, mlps,
                                                                                                  strict=True)]))
            in_dim = sum(ch[-1] for ch in mlps)
            cat_dims.append(in_dim)
        self.set_abstract_msg = nn.ModuleList(levels)
        # Trained but unused by the outputs (the feature propagation starts from the last level): kept so
        # the checkpoint loads strictly.
        self.set_abstract_final = mlp([640, 256, 512, 1024])
        fp_in = [cat_dims[2] + cat_dims[2], 256 + cat_dims[1], 128 + cat_dims[0]]
        fp_out = [[256, 256], [256, 128], [128, 128, 128]]
        self.feat_prop = nn.ModuleList([FeaturePropagation([i, *o]) for i, o in zip(fp_in, fp_out, strict=True)])
        self.multihead = nn.ModuleList([
            nn.Sequential(nn.Conv1d(131, 128, 1), nn.BatchNorm1d(128), nn.Dropout(p), nn.Conv1d(128, out, 1))
            for out, p in ((1, 0.5), (3, 0.7), (3, 0.7), (1, 0.0))])

    @classmethod
    def pretrained(cls, device: str | torch.device = "cpu") -> ContactGraspNet:
        """The network with the ``cgn-pytorch`` weights, in eval mode."""
        net = cls()
        state = torch.load(checkpoint_path(), map_location="cpu", weights_only=True)["state_dict"]
        net.load_state_dict(state, strict=True)
        return net.to(device).eval()

    @torch.no_grad()
    def forward(self, pos: torch.Tensor, generators: list[torch.Generator] | None = None,
                max_width: float = 0.08) -> dict[str, torch.Tensor]:
        """Per-point grasps for a batch of clouds.

        Args:
            pos: ``(B, N, 3)`` clouds (N >= 2048), z-up, centered.
            generators: one per cloud, seeds its farthest-point sampling starts (a cloud's result does not
                depend on the others in the batch).
            max_width: the gripper's opening (m): predicted widths are clipped to ``[0, max_width]``.

        Returns:
            dict with ``points (B, 2048, 3)`` contact points, ``logits (B, 2048)``, ``approach`` and
            ``closing`` ``(B, 2048, 3)`` unit vectors, ``width (B, 2048)`` (m), ``index (B, 2048)``
            (the contact points' indices in ``pos``).
        """
        first = farthest_point_sampling(pos, self.CENTERS[0], generators)
        x, cur_pos, centers_idx = pos.new_zeros(*pos.shape[:2], 0), pos, first
        skips = [(x, pos)]
        for level, modules in enumerate(self.set_abstract_msg):
            if level > 0:
                centers_idx = farthest_point_sampling(cur_pos, self.CENTERS[level], generators)
            balls = ball_queries(cur_pos, centers_idx, tuple(m.r for m in modules))
            x = torch.cat([m(x, cur_pos, centers_idx, *ball) for m, ball in zip(modules, balls, strict=True)], dim=-1)
            cur_pos = _gather(cur_pos, centers_idx)
            skips.append((x, cur_pos))
        # skips: input, level 1 (2048), level 2 (512), level 3 (128); propagate 128 -> 128 -> 512 -> 2048.
        for fp, (x_skip, pos_skip) in zip(self.feat_prop, reversed(skips[1:]), strict=True):
            x = fp(x, cur_pos, x_skip, pos_skip)
            cur_pos = pos_skip
        feat = torch.cat([cur_pos, x], dim=-1).transpose(1, 2)  # (B, 131, 2048)
        heads = [h(feat).transpose(1, 2) for h in self.multihead]
        logits, z1, z2, w = heads[0][..., 0], heads[1], heads[2], heads[3][..., 0]
        closing = z1 / torch.linalg.norm(z1, dim=-1, keepdim=True)
        approach = z2 - (closing * z2).sum(-1, keepdim=True) * closing
        approach = approach / torch.linalg.norm(approach, dim=-1, keepdim=True)
        return dict(points=cur_pos, logits=logits, approach=approach, closing=closing,
                    width=w.clamp(min=0.0, max=max_width), index=first)


def grasp_frames(points: torch.Tensor, approach: torch.Tensor, closing: torch.Tensor, width: torch.Tensor,
                 gripper_depth: float = 0.1034) -> torch.Tensor:
    """Contact-GraspNet's 6-D grasps: ``(..., 4, 4)`` hand-base poses (x closing, z approach).

    The base sits ``gripper_depth`` behind the point midway between the contact and the opposite finger.
    """
    y = torch.cross(approach, closing, dim=-1)
    y = y / torch.linalg.norm(y, dim=-1, keepdim=True)
    pose = torch.zeros(*points.shape[:-1], 4, 4, dtype=points.dtype, device=points.device)
    pose[..., :3, 0], pose[..., :3, 1], pose[..., :3, 2] = closing, y, approach
    pose[..., :3, 3] = points - gripper_depth * approach + 0.5 * width[..., None] * closing
    pose[..., 3, 3] = 1.0
    return pose
