"""``python -m grt.bench deform [--faces N]``: time the Jacobian-field deformer on a ~N-face mesh.

Builds a vase-like solid of revolution with a bump (well-shaped triangles, ~N faces), 8 handles
spread over its upper half and a few hundred anchors on its lower tenth, then reports setup,
factorization, per-candidate times of both methods, a population of 10 in one call against ten calls of
one in the same run (their ratio: below 1 when batching pays), memory, their Chamfer gap and constraint
errors.
The last printed line is one JSON object (for scripts); the paper's 22 s per deformation (APAP on
an RTX 4090) is the reference of ``speedup_vs_paper``.
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np
import scipy.sparse as sp
import trimesh

from grt.geometry.chamfer import chamfer_distance
from grt.geometry.deform import JacobianFieldDeformer, ShapeDeformer
from grt.geometry.solver import SparseCholesky
from grt.objects.shapes import revolve, to_trimesh

PAPER_S_PER_DEFORMATION = 22.0


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def bench_mesh(faces: int) -> trimesh.Trimesh:
    """A vase with a bump, ~``faces`` triangles, unit-cube-sized (about 1 unit tall)."""
    z = np.linspace(0, 1, 200)
    r = 0.3 + 0.08 * np.sin(2.5 * np.pi * z) + 0.06 * np.exp(-((z - 0.7) / 0.08) ** 2)
    prof = np.concatenate([[[0, 0]], np.stack([r, z], 1), [[0, 1]]])

    def build(segments: int) -> trimesh.Trimesh:
        return to_trimesh(revolve(prof, segments=segments, min_spacing=1e-3))

    trial = build(64)
    segs = max(8, int(round(64 * np.sqrt(faces / len(trial.faces)))))
    return build(segs)


def pick_constraints(mesh: trimesh.Trimesh, n_handles: int = 8, n_anchors: int = 300, seed: int = 0):
    """Handles spread over the upper half (farthest-point), anchors among the lowest 10 % in z."""
    v = np.asarray(mesh.vertices)
    rng = np.random.default_rng(seed)
    z = v[:, 2]
    upper = np.flatnonzero(z > np.quantile(z, 0.5))
    handles = [int(rng.choice(upper))]
    d = np.linalg.norm(v[upper] - v[handles[0]], axis=1)
    for _ in range(n_handles - 1):
        handles.append(int(upper[np.argmax(d)]))
        d = np.minimum(d, np.linalg.norm(v[upper] - v[handles[-1]], axis=1))
    low = np.flatnonzero(z <= np.quantile(z, 0.1))
    anchors = rng.choice(low, size=min(n_anchors, low.size), replace=False)
    return np.array(handles), np.sort(anchors)


def _time(fn, repeat: int, rounds: int = 5) -> float:
    """Seconds per call of ``fn``: the best of ``rounds`` rounds of ``repeat`` calls (on a busy machine the
    mean of one round measured the other processes as much as ``fn``)."""
    fn()
    best = float("inf")
    for _ in range(rounds):
        t = time.perf_counter()
        for _ in range(repeat):
            fn()
        best = min(best, (time.perf_counter() - t) / repeat)
    return best


def solver_figures(core: JacobianFieldDeformer) -> dict:
    """Factorization and 16-RHS solve times of each available Cholesky backend."""
    A = (core.L.T @ core.L + core.lam * (core.Ka.T @ core.Ka)).tocsc()
    b = np.random.default_rng(0).standard_normal((A.shape[0], 16))
    out = {}
    for backend in ("cholespy", "scipy"):
        try:
            t = time.perf_counter()
            s = SparseCholesky(sp.csc_matrix(A), backend=backend)
            f_s = time.perf_counter() - t
        except ImportError:
            continue
        out[backend] = {"factor_s": round(f_s, 4), "solve16_ms": round(1e3 * _time(lambda s=s: s.solve(b), 5), 2)}
    return out


def run(faces: int = 10000, sigma: float = 0.02, seed: int = 0) -> dict:
    baseline = _rss_mb()
    mesh = bench_mesh(faces)
    v0, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    handles, anchors = pick_constraints(mesh, seed=seed)
    t = time.perf_counter()
    exact = JacobianFieldDeformer(v0, f, handles, anchors, method="exact")
    setup_s = time.perf_counter() - t
    apap = JacobianFieldDeformer(v0, f, handles, anchors, method="apap")
    thetas = sigma * np.random.default_rng(seed).standard_normal((10, len(handles), 3))
    exact_1 = _time(lambda: exact(thetas[0]), 20)
    exact_10 = _time(lambda: exact(thetas), 10)
    exact_10x1 = _time(lambda: [exact(t) for t in thetas], 10)  # the baseline a population must beat
    shaped = ShapeDeformer(mesh, handles, anchors, method="exact")  # + Procrustes and meters, as a run does
    shape_10 = _time(lambda: shaped.vertices(thetas), 10)
    shape_10x1 = _time(lambda: [shaped.vertices(t) for t in thetas], 10)
    t = time.perf_counter()
    ve = exact(thetas[:4])
    va = apap(thetas[:4])
    apap_s = (time.perf_counter() - t - exact_10) / 4
    cd = [chamfer_distance(trimesh.Trimesh(a, f, process=False), trimesh.Trimesh(e, f, process=False), 20000)
          for a, e in zip(va, ve, strict=False)]
    solvers = solver_figures(exact)
    return {
        "vertices": len(v0), "faces": len(f), "handles": len(handles), "anchors": len(anchors),
        "sigma_unit_cube": sigma, "backend": exact.solver.backend,
        "factor_s": solvers.get(exact.solver.backend, {}).get("factor_s"), "setup_exact_s": round(setup_s, 3),
        "exact_ms_per_candidate": round(1e3 * exact_1, 3), "exact_population10_ms": round(1e3 * exact_10, 3),
        "exact_10_calls_ms": round(1e3 * exact_10x1, 3), "population_vs_calls": round(exact_10 / exact_10x1, 3),
        "shape_population10_ms": round(1e3 * shape_10, 3), "shape_10_calls_ms": round(1e3 * shape_10x1, 3),
        "shape_population_vs_calls": round(shape_10 / shape_10x1, 3),
        "apap_s_per_candidate": round(apap_s, 3),
        "peak_rss_mb": round(_rss_mb(), 1), "baseline_rss_mb": round(baseline, 1),
        "chamfer_apap_vs_exact": float(f"{np.mean(cd):.3e}"),
        "max_handle_residual_exact": float(f"{np.abs(ve[:, handles] - (v0[handles] + thetas[:4])).max():.3e}"),
        "max_handle_residual_apap": float(f"{np.abs(va[:, handles] - (v0[handles] + thetas[:4])).max():.3e}"),
        "max_anchor_drift_exact": float(f"{np.abs(ve[:, anchors] - v0[anchors]).max():.3e}"),
        "speedup_vs_paper": round(PAPER_S_PER_DEFORMATION / exact_1),
        "speedup_vs_paper_apap": round(PAPER_S_PER_DEFORMATION / apap_s, 1),
        "solvers": solvers,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m grt.bench deform", description=__doc__.split("\n\n")[0])
    ap.add_argument("--faces", type=int, default=10000, help="approximate face count of the test mesh")
    ap.add_argument("--sigma", type=float, default=0.02, help="handle displacement std, unit-cube units")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    r = run(args.faces, args.sigma, args.seed)
    print(f"mesh: {r['vertices']} vertices, {r['faces']} faces; {r['handles']} handles, {r['anchors']} anchors")
    print(f"setup (operators, {r['backend']} factorization {r['factor_s']} s, exact basis): {r['setup_exact_s']} s")
    print(f"exact: {r['exact_ms_per_candidate']} ms per candidate, {r['exact_population10_ms']} ms per population "
          f"of 10; handles met to {r['max_handle_residual_exact']}, anchors drift {r['max_anchor_drift_exact']} "
          "(unit-cube units, before Procrustes)")
    print(f"population of 10 in one call / ten calls of one: {r['exact_population10_ms']} / {r['exact_10_calls_ms']} ms "
          f"= {r['population_vs_calls']} (deformation); {r['shape_population10_ms']} / {r['shape_10_calls_ms']} ms = "
          f"{r['shape_population_vs_calls']} (with Procrustes and meters, ShapeDeformer.vertices, as a run calls it)")
    print(f"apap (Adam 300 steps): {r['apap_s_per_candidate']} s per candidate; Chamfer apap vs exact "
          f"{r['chamfer_apap_vs_exact']} (squared, unit cube) at sigma {r['sigma_unit_cube']}")
    print(f"memory: peak {r['peak_rss_mb']} MB (baseline {r['baseline_rss_mb']} MB); solvers: {r['solvers']}")
    print(f"vs paper's {PAPER_S_PER_DEFORMATION} s per deformation: exact x{r['speedup_vs_paper']}, "
          f"apap x{r['speedup_vs_paper_apap']}")
    print(json.dumps(r))


if __name__ == "__main__":
    main()
