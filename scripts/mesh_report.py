"""Measure the mesh input pipeline on the real test meshes and a few built-ins: ``python scripts/mesh_report.py``.

One Markdown row per object (input faces, prepared faces, repairs, volume ratio, Hausdorff and Chamfer
distance in mm, prepare seconds), with the apps' settings (``mesh.remesh=auto``), then the 300k-face
sphere of issue 12 (generated, in memory) and, as the last line, the rows as JSON. The same rows come from
:func:`grt.geometry.mesh.prepare_report` (``python -m grt.bench meshes`` builds on it).
"""

from __future__ import annotations

import argparse
import json
import time

import trimesh

from grt.bench.meshes import REAL, REAL_SCALES
from grt.geometry.mesh import prepare_mesh, prepare_report
from grt.geometry.prepare import MeshSettings

BUILTINS = ("mug", "plug", "bottle")


def sphere_300k_row() -> dict:
    """The issue's very fine input: a 327,680-face icosphere (5 cm radius), prepared in memory."""
    fine = trimesh.creation.icosphere(7, radius=0.05)
    start = time.perf_counter()
    mesh = prepare_mesh(fine, settings=MeshSettings(remesh="auto"))
    prep = mesh.metadata["grt_prepare"]
    return {"object": "icosphere(7) 300k", "input_faces": len(fine.faces), "prepared_faces": len(mesh.faces),
            "prepared_vertices": len(mesh.vertices), "repairs": prep["repairs"], "remesh": prep["remesh"]["decision"],
            **{k: prep["fidelity"][k] for k in ("volume_ratio", "hausdorff_mm", "chamfer_mm")},
            "prepare_s": round(time.perf_counter() - start, 3), "timings_s": prep["timings_s"]}


def markdown(rows: list[dict]) -> str:
    lines = ["| object | input faces | prepared faces | repairs | volume ratio | Hausdorff mm | Chamfer mm | prepare s |",
             "|---|---:|---:|---|---:|---:|---:|---:|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['object']} | | | refused: {r['error'].split(': ', 1)[-1]} | | | | {r['prepare_s']:.2f} |")
            continue
        repairs = "; ".join(r["repairs"]) or "none"
        lines.append(f"| {r['object']} | {r['input_faces']} | {r['prepared_faces']} | {repairs} | {r['volume_ratio']:.4f} "
                     f"| {r['hausdorff_mm']:.3f} | {r['chamfer_mm']:.3f} | {r['prepare_s']:.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--no-300k", action="store_true", help="skip the 300k-face sphere")
    args = ap.parse_args(argv)
    rows = []
    for name, scale in REAL_SCALES.items():
        row = prepare_report(REAL / name, scale=scale)
        row["object"] = f"{name} (x{scale:g})"
        rows.append(row)
    rows += [prepare_report(name) for name in BUILTINS]
    if not args.no_300k:
        rows.append(sphere_300k_row())
    print(markdown(rows))
    print(json.dumps(rows))
    return rows


if __name__ == "__main__":
    main()
