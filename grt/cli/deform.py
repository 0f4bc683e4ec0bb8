"""``grt-deform`` (``python -m grt.deform MESH --handles H.txt --anchors A.txt --out OUT.obj``): deform a mesh from handle targets.

``H.txt`` and ``A.txt`` hold one ``index x y z`` per line, as in APAP: a vertex index of ``MESH`` and
its target position in the mesh's own frame (meters for GRT's objects). Anchors' positions are
their fixed targets. Blank lines and lines starting with ``#`` are ignored. ``MESH`` is a mesh file
or a built-in object name (``python -m grt.objects`` lists them).

Unlike :class:`grt.geometry.deform.ShapeDeformer` (which keeps anchors at rest), the CLI honours
the anchor targets given in the file; ``--no-align`` skips the rigid Procrustes re-alignment of the
result on the anchors. ``OUT`` is written whole or not at all, into an existing folder; a mistake (bad
mesh or target file, unsupported ``--out`` format, missing or read-only folder) is one ``error:`` line
and exit code 2, Ctrl-C exit code 130. Nothing the user has is overwritten unasked: an ``--out`` that is
one of the command's inputs (the mesh, the handle or anchor file, also through a link) is always refused,
and an ``--out`` that is another existing file is refused unless ``--overwrite`` is given.

Indices count the vertices of the file as written (an OBJ's ``v`` lines). When loading or repair
changes the vertices (an unreferenced vertex dropped, duplicates merged, ``--remesh``), each index is
carried to the prepared mesh's vertex nearest to its file position and the tool says so; a vertex that
has none within half an edge, or two indices that land on one vertex, is refused.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import trimesh

from grt.cli._common import AppParser, exit_on_user_error, write_output
from grt.errors import OutputError, UserError, check_output_file
from grt.geometry.deform import METHODS, JacobianFieldDeformer, check_indices
from grt.geometry.indices import IndexMapError, carry_indices, file_vertices
from grt.geometry.mesh import UnitCubeFrame, align_to_anchors, load_mesh
from grt.geometry.prepare import REMESH_MODES, MeshSettings
from grt.geometry.prepare import describe as describe_preparation

OUT_SUFFIXES = (".obj", ".stl", ".ply", ".glb", ".off")  # formats load_mesh reads back


class TargetFileError(UserError):
    """A handle/anchor file that cannot be parsed; the message names the file and line."""


class DeformInputError(UserError):
    """Targets or settings the deformation cannot use (bad indices, ``--lam`` <= 0, an unanchored part)."""


def read_targets(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Parse an ``index x y z`` file.

    Returns:
        ``(K,)`` int vertex indices and ``(K, 3)`` float target positions.

    Raises:
        TargetFileError: missing, empty or malformed file (names the file and the line).
    """
    path = Path(path)
    if not path.is_file():
        raise TargetFileError(f"{path}: file not found")
    idx, pos = [], []
    for n, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = text.replace(",", " ").split()
        try:
            if len(parts) != 4:
                raise ValueError(f"expected 4 values 'index x y z', got {len(parts)}")
            i, xyz = int(parts[0]), [float(p) for p in parts[1:]]
        except ValueError as exc:
            raise TargetFileError(f"{path}:{n}: cannot parse {line.strip()!r} ({exc})") from None
        if not np.all(np.isfinite(xyz)):
            raise TargetFileError(f"{path}:{n}: target position is NaN or infinite")
        idx.append(i)
        pos.append(xyz)
    if not idx:
        raise TargetFileError(f"{path}: no 'index x y z' lines found (the file is empty)")
    return np.array(idx, np.int64), np.array(pos, np.float64)


def deform_to_targets(mesh: trimesh.Trimesh, handles: np.ndarray, handle_pos: np.ndarray, anchors: np.ndarray,
                      anchor_pos: np.ndarray, method: str = "exact", lam: float = 1.0,
                      align: bool = True) -> tuple[np.ndarray, float]:
    """Deform ``mesh`` so handles reach ``handle_pos`` with anchors held (softly) at ``anchor_pos``.

    Works in the mesh's unit-cube frame (as ``ShapeDeformer``) and returns to the mesh's units.

    Returns:
        ``(V, 3)`` deformed vertices and the max handle residual (units of the mesh, before alignment).
    """
    handles, anchors = check_indices(handles, anchors, len(mesh.vertices))
    frame = UnitCubeFrame.fit(np.asarray(mesh.vertices))
    v0 = frame.to_unit(np.asarray(mesh.vertices, np.float64))
    core = JacobianFieldDeformer(v0, mesh.faces, handles, anchors, lam=lam, method=method)
    a_unit = frame.to_unit(anchor_pos)
    core.set_anchor_targets(a_unit)
    theta = frame.to_unit(handle_pos) - v0[handles]
    rest = core.solve_vertices((core.G @ v0)[None])[0] - v0  # offset from moved anchors at rest J
    if method == "exact":
        out = core(theta - rest[handles]) + rest
    else:
        out = core(theta)
    residual = float(np.abs(out[handles] - frame.to_unit(handle_pos)).max() * frame.scale)
    if align and len(anchors) >= 3:
        out = align_to_anchors(out, anchors, a_unit)
    return frame.to_metric(out), residual


def check_not_overwritten(out: Path, inputs: dict[str, str], overwrite: bool) -> None:
    """Refuse an ``--out`` that is one of the command's ``inputs`` (what -> path; also through a link or a
    hard link: the same file), always, and any other existing file unless ``overwrite``.

    Raises:
        OutputError: names the file and what to do.
    """
    if not out.exists():
        return
    for what, path in inputs.items():
        if Path(path).exists() and os.path.samefile(out, path):
            raise OutputError(f"--out {out} is {what} ({path}): writing it would replace the input; give another "
                              "--out (the input is never overwritten)")
    if not overwrite:
        raise OutputError(f"--out {out} already exists; give another --out, or --overwrite to replace it")


def main(argv: list[str] | None = None) -> int:
    ap = AppParser("deform", description=__doc__.split("\n\n")[0])
    ap.add_argument("mesh", help="mesh file (OBJ/STL/PLY/GLB/OFF) or built-in object name")
    ap.add_argument("--handles", required=True, help="file of 'index x y z' handle targets")
    ap.add_argument("--anchors", required=True, help="file of 'index x y z' anchor targets")
    ap.add_argument("--out", required=True,
                    help=f"output mesh file ({', '.join(OUT_SUFFIXES)}) in an existing folder")
    ap.add_argument("--method", choices=METHODS, default="exact")
    ap.add_argument("--lam", type=float, default=1.0, help="anchor weight (APAP: 1.0)")
    ap.add_argument("--no-align", action="store_true", help="skip Procrustes alignment on the anchors")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace --out if it is an existing file (never one of this command's inputs)")
    ap.add_argument("--remesh", choices=REMESH_MODES, default="off",
                    help="remesh the input first (off: a valid file keeps its vertices and indices exactly)")
    args = ap.parse_args(argv)
    with exit_on_user_error(TargetFileError, DeformInputError, IndexMapError):
        out = check_output_file(args.out, OUT_SUFFIXES)  # before any work
        check_not_overwritten(out, {"the input mesh": args.mesh, "--handles": args.handles,
                                    "--anchors": args.anchors}, args.overwrite)
        mesh = load_mesh(args.mesh, settings=MeshSettings(remesh=args.remesh))
        h_idx, h_pos = read_targets(args.handles)
        a_idx, a_pos = read_targets(args.anchors)
        mapped = []
        if Path(args.mesh).is_file():  # indices count the file's vertices: carry them to the prepared mesh
            moved = carry_indices({"handles": h_idx, "anchors": a_idx}, file_vertices(args.mesh), mesh)
            h_idx, a_idx = moved["handles"].indices, moved["anchors"].indices
            mapped = [f"{name}: {m.changed} of {len(m.indices)} indices changed (largest distance {m.distance:.3g} "
                      "mesh units)" for name, m in moved.items() if m.changed]
        try:
            verts, residual = deform_to_targets(mesh, h_idx, h_pos, a_idx, a_pos, args.method, args.lam,
                                                not args.no_align)
        except ValueError as exc:  # indices out of range or shared, --lam <= 0, a component without anchor
            raise DeformInputError(f"cannot deform {args.mesh} with {args.handles} and {args.anchors}: {exc}") \
                from None
        data = trimesh.Trimesh(verts, mesh.faces, process=False).export(file_type=out.suffix.lower()[1:])
        write_output(out, data)
    for line in describe_preparation(mesh):
        print(line)
    for line in mapped:
        print(f"indices of {args.mesh} carried to the prepared mesh (nearest vertex): {line}")
    print(f"method={args.method} handles={len(h_idx)} anchors={len(a_idx)} "
          f"max handle residual={residual:.3e} (mesh units, before alignment)")
    print(f"wrote {out} ({len(verts)} vertices, {len(mesh.faces)} faces)")
    return 0


def cli() -> None:
    """``grt-deform``."""
    sys.exit(main())
