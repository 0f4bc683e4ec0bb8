"""Why does the swapped compound actor behave unlike the stock one? One hypothesis per variant of the swap.

Each variant changes one thing in how GRT builds PullCubeTool-v1's L-shaped tool (a handle box of density 500
and a hook box of 1000, overlapping) and replays the motion planner's stock episodes open-loop on it
(:mod:`grt.tasks.maniskill.fidelity`): the tool's largest distance and angle from the stock tool over the
episode, and the step where it first parts by 1 mm or 1 deg. The body's mass, centre of mass and principal
moments are printed beside. Run from the repository root (the planner needs its own numpy: `make motionplanning`):

    .venv/bin/python experiments/maniskill/fidelity/hypotheses.py --episodes 4 --out experiments/maniskill/fidelity/hypotheses.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

#: variant -> what it changes (the first is GRT before the fix, the second after it)
VARIANTS = {
    "parts_mass": "CoACD's parts of the remeshed L, each with the density of the stock box nearest it (before the fix)",
    "mesh_mass": "the same parts; mass, centre of mass and inertia from the mesh under the boxes' densities (the fix)",
    "box_hulls": "the stock boxes themselves as convex hulls (exact geometry and mass)",
    "box_hulls_split": "each stock box as 4 convex slabs along its length",
    "tool_patch_radius": "mesh_mass; torsional patch radius 20 mm on the tool",
    "tool_contact_offset": "mesh_mass; contact offset 5 mm on the tool (stock: 20 mm)",
    "tool_friction": "mesh_mass; friction 0.6 on the tool (stock: 0.3)",
    "solver_iterations": "mesh_mass; 40 position iterations on the tool (stock: 15)",
    "handle_primitive": "handle as PhysX's box primitive, hook as a convex hull",
    "hook_primitive": "hook as PhysX's box primitive, handle as a convex hull",
    "primitives": "both boxes as PhysX box primitives (the harness itself: must be 0)",
    "pcm_off_parts_mass": "PhysX's persistent contact manifold off (both sides): parts_mass",
    "pcm_off_box_hulls": "PhysX's persistent contact manifold off (both sides): box_hulls",
}


def _slabs(verts: np.ndarray, count: int = 4) -> list[np.ndarray]:
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    axis = int(np.argmax(hi - lo))
    cuts = np.linspace(lo[axis], hi[axis], count + 1)
    out = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        box_lo, box_hi = lo.copy(), hi.copy()
        box_lo[axis], box_hi[axis] = a, b
        out.append(np.array([[x, y, z] for x in (box_lo[0], box_hi[0]) for y in (box_lo[1], box_hi[1])
                             for z in (box_lo[2], box_hi[2])]))
    return out


def _patch(variant: str) -> None:
    """Change :class:`ActorSwap` for ``variant`` (this process only)."""
    import sapien
    from sapien import physx

    from grt.tasks.maniskill import swap as swap_module

    build_one, mass = swap_module.ActorSwap._build_one, swap_module.ActorSwap._mass_properties
    primitive = {"handle_primitive": {0}, "hook_primitive": {1}, "primitives": {0, 1}}.get(variant, set())

    def _mass_properties(self, builder, cand, records, scale):
        return None if variant.endswith("parts_mass") else mass(self, builder, cand, records, scale)

    def _build_one(self, builder, name, cand, records, scale):
        boxes = [np.asarray(r.mesh.vertices) for r in records if r.mesh is not None]
        if primitive:
            actor, hull = _with_primitives(builder, name, cand, records, primitive)
        else:
            if "box_hulls" in variant:
                parts = [p for b in boxes for p in _slabs(b)] if variant == "box_hulls_split" else boxes
                cand = swap_module.Candidate(cand.mesh, parts)
            actor, hull = build_one(self, builder, name, cand, records, scale)
        body = actor._objs[0].find_component_by_type(physx.PhysxRigidDynamicComponent)
        for shape in body.collision_shapes:
            if variant == "tool_patch_radius":
                shape.set_patch_radius(0.02)
                shape.set_min_patch_radius(0.02)
            elif variant == "tool_contact_offset":
                shape.set_contact_offset(0.005)
            elif variant == "tool_friction":
                shape.physical_material = physx.PhysxMaterial(0.6, 0.6, 0.0)
        if variant == "solver_iterations":
            body.set_solver_position_iterations(40)
        return actor, hull

    def _with_primitives(builder, name, cand, records, which):
        from grt.tasks.scene import attach_convex_parts

        builder.collision_records, builder.visual_records = [], []
        stock_component = builder.build_physx_component

        def build_physx_component(link_parent=None):
            component = stock_component(link_parent)
            for k, r in enumerate(records):
                if k in which:
                    half = np.ptp(np.asarray(r.mesh.vertices) @ r.pose[:3, :3], axis=0) / 2
                    shape = physx.PhysxCollisionShapeBox(half_size=half, material=r.material)
                    shape.set_local_pose(sapien.Pose(r.pose))
                    shape.set_density(r.density)
                    shape.set_collision_groups(builder.collision_groups)
                    component.attach(shape)
                else:
                    attach_convex_parts(component, [np.asarray(r.mesh.vertices)], r.material, r.density,
                                        builder.collision_groups)
            return component

        builder.build_physx_component = build_physx_component
        return swap_module._ORIGINAL_BUILD(builder, name), np.concatenate([np.asarray(r.mesh.vertices) for r in records])

    swap_module.ActorSwap._build_one = _build_one
    swap_module.ActorSwap._mass_properties = _mass_properties


def _body(session) -> dict:
    from sapien import physx

    body = session.swap.build_of(0).actor._objs[0].find_component_by_type(physx.PhysxRigidDynamicComponent)
    return {"mass_kg": round(float(body.mass), 6), "com_mm": (np.asarray(body.cmass_local_pose.p) * 1000).round(3).tolist(),
            "moments": np.sort(np.asarray(body.inertia)).round(9).tolist()}


def measure(task: dict, policy: dict, vertices, faces, parts, seeds: list[int], variant: str) -> dict:
    """One variant in this process (a worker with the planner's numpy): the body and the open-loop replays."""
    import trimesh

    from grt.evaluators.pool import build_session
    from grt.tasks.maniskill import fidelity

    _patch(variant)
    if variant.startswith("pcm_off"):
        task = {**task, "session": {**task["session"], "sim_config": {"scene_config": {"enable_pcm": False}}}}
    session = build_session(task, policy)
    try:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        session.load_object(None, None)
        session.reset(seeds[0], rebuild=True)
        stock = _body(session)
        session.load_object(mesh, parts)
        session.reset(seeds[0], rebuild=True)
        out = {"what": VARIANTS[variant], "stock_body": stock, "swap_body": _body(session), "episodes": []}
        for seed in seeds:
            session.load_object(None, None)
            record = fidelity.check(session, (mesh, parts), fidelity.record(session, seed), "policy")
            out["episodes"].append({"seed": seed, **{k: record[k] for k in ("steps", "replay", "nudge", "swap")}})
        return out
    finally:
        session.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--variants", nargs="*", default=list(VARIANTS))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()

    from hydra import compose, initialize_config_dir

    from grt.cli._common import CONF_DIR
    from grt.config import plain
    from grt.evaluators.collision import make_collision
    from grt.evaluators.worker_env import run_in_worker, worker_path
    from grt.geometry.mesh import load_mesh
    from grt.geometry.prepare import MeshSettings
    from grt.redteam import episode_seeds
    from grt.tasks import task_object

    with initialize_config_dir(CONF_DIR, version_base="1.3"):
        cfg = compose("calibrate", overrides=["task=pull_cube_tool", "policy=motion_planner"])
    task, policy = plain(cfg.task), plain(cfg.policy)
    mesh = load_mesh(task_object(cfg.task, cfg.object, cfg.paths.cache_dir), settings=MeshSettings.from_config(cfg.mesh))
    parts = make_collision("fast", mesh, None, f"{cfg.paths.cache_dir}/coacd", int(cfg.max_hull_vertices)).parts(mesh)
    seeds = [int(s) for s in episode_seeds(0, args.episodes)]
    results = json.loads(args.out.read_text()) if args.out.is_file() else {}
    for variant in args.variants:
        results[variant] = run_in_worker(worker_path(policy), measure, task, policy, mesh.vertices, mesh.faces,
                                         parts, seeds, variant)
        swap = [e["swap"] for e in results[variant]["episodes"]]
        print(f"{variant:22s} max mm {[s['max_mm'] for s in swap]}  max deg {[s['max_deg'] for s in swap]}  "
              f"onset {[s['onset_step'] for s in swap]}  body {results[variant]['swap_body']}", flush=True)
        args.out.write_text(json.dumps(results, indent=1))
    print("stock body", results[args.variants[0]]["stock_body"])


if __name__ == "__main__":
    main()
