"""Re-run trials of a finished search: replay one trial exactly, and film the report's videos.

A trial's outcome is a function of (mesh, episode seed) only (every task rebuilds its scene before a
trial), and the journal holds both: each candidate's ``theta`` (and the ``mesh_hash`` of the mesh it
made) and each trial's seed. :func:`replay` rebuilds the candidate's mesh from the run's ``nominal.obj``,
``handles.json`` and deformer config, checks its hash against the journal's, makes its collision parts as
the run's evaluator did, builds the task session of the run's config in this process and runs that one
seed, optionally filming it from the task's fixed render camera. :func:`render_videos` does that after a
search for the nominal object and the top CrashShapes on one failing episode seed of each
(``report.videos``), into ``videos/`` with an index the report reads. Rendering happens only here, never
during the search.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import re
import time
from pathlib import Path

import numpy as np

from grt.errors import UserError
from grt.fileio import write_text_atomic
from grt.tasks.renderer import renderer_problem

log = logging.getLogger("grt.rerun")

CANDIDATE = re.compile(r"it(\d+)_c(\d+)")
VIDEO_FPS = 20
VIDEO_SIZE = 320  # pixels, square
MAX_FRAMES = 40  # about, per episode
MAX_VIDEO_BYTES = 2_000_000


class ReplayError(UserError):
    """A trial that cannot be replayed as asked; the message names the problem and the fix."""


def parse_candidate(text: str) -> tuple[int, int]:
    """``it3_c5`` -> (3, 5); ``nominal`` -> (0, 0)."""
    if text == "nominal":
        return 0, 0
    m = CANDIDATE.fullmatch(text.strip())
    if not m:
        raise ReplayError(f"candidate={text!r}: give it<iteration>_c<index> (e.g. it3_c5, as the report names "
                          "candidates) or nominal")
    return int(m.group(1)), int(m.group(2))


def _records(run_dir: Path) -> list[dict]:
    """The journal's records, read only (a replay must not cut a run's interrupted last line)."""
    from grt.report.html import read_journal

    path = run_dir / "journal.jsonl"
    if not path.is_file():
        raise ReplayError(f"{run_dir} has no journal.jsonl: not a GRT run folder; give the folder python -m grt.run "
                          "wrote")
    return read_journal(path)[0]


def check_trial(run_dir: Path, iteration: int, candidate: int, seed: int) -> dict:
    """The journal's record of trial ``seed`` of a candidate (read before any simulator starts).

    Raises:
        ReplayError: no such candidate, a candidate never simulated, or not one of its seeds.
    """
    rec = next((r for r in _records(Path(run_dir)) if (r["iteration"], r["candidate"]) == (iteration, candidate)), None)
    name = "nominal" if iteration == 0 else f"it{iteration}_c{candidate}"
    if rec is None:
        raise ReplayError(f"{name} is not in {Path(run_dir) / 'journal.jsonl'}; the report's trial table names the "
                          "candidates (it<t>_c<i>, nominal)")
    if rec.get("valid") is False:
        raise ReplayError(f"{name} was refused as implausible and never simulated: no trial to replay")
    trial = next((t for t in rec.get("trials", []) if int(t["seed"]) == int(seed)), None)
    if trial is None:
        seeds = [t["seed"] for t in rec.get("trials", [])]
        raise ReplayError(f"seed {seed} is not a trial of {name}; its seeds: "
                          f"{', '.join(map(str, seeds[:8]))}{' ...' if len(seeds) > 8 else ''}")
    return trial


def first_failure(run_dir: Path) -> tuple[str, int]:
    """The rank-1 CrashShape's first failing trial (candidate name, seed); in a run that found no CrashShape,
    its best candidate's (``best_candidates`` in ``summary.json``)."""
    summary_path = run_dir / "summary.json"
    records = _records(run_dir)
    by_key = {(r["iteration"], r["candidate"]): r for r in records}
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    shapes = summary.get("crashshapes") or summary.get("best_candidates") or []
    if shapes:
        ranked = [by_key.get((s["iteration"], s["candidate"])) for s in shapes]
    else:  # partial run: its lowest candidate so far
        from grt.outputs import crash_records

        ranked = crash_records(records, 1)
    for rec in ranked[:1]:
        if rec is None:
            continue
        for t in rec.get("trials", []):
            if t.get("mode") != "success":
                return f"it{rec['iteration']}_c{rec['candidate']}", int(t["seed"])
        raise ReplayError(f"the rank-1 CrashShape it{rec['iteration']}_c{rec['candidate']} failed no trial: nothing "
                          "to replay by default; give candidate=... seed=... (the report lists every trial's seed)")
    raise ReplayError(f"{run_dir}: no CrashShape in the journal yet; give candidate=nominal seed=<a seed of the "
                      "journal>")


class RunReplayer:
    """The run's nominal mesh, deformer, collision and one task session in this process, to re-run trials.

    Args:
        run_dir: a red-team run folder.
        here: run the trials in this process even when the run's policy names a ``worker_path`` (a Python of
            its own, e.g. the motion planners' numpy 1.26); ``False`` runs them in a child process started with
            that path first, as the run's simulator workers were (:class:`_ChildReplayer`).
    """

    def __init__(self, run_dir: Path, here: bool = False):
        import trimesh

        from grt.config import saved_plan
        from grt.evaluators.collision import make_collision
        from grt.geometry.deform import ShapeDeformer
        from grt.runfolder.record import load_run_config
        from grt.selectors.base import HandleSet

        self.run_dir = Path(run_dir)
        self.plan = saved_plan(load_run_config(self.run_dir), self.run_dir)
        for name in ("nominal.obj", "handles.json"):
            if not (self.run_dir / name).is_file():
                raise ReplayError(f"{self.run_dir / name} is missing (deleted?): the candidate's mesh cannot be "
                                  "rebuilt; restore it or replay another run")
        self.records = {(r["iteration"], r["candidate"]): r for r in _records(self.run_dir)}
        self.nominal = self._nominal(trimesh.load(self.run_dir / "nominal.obj", process=False, force="mesh"))
        self.notes: list[str] = []
        hs = HandleSet.from_json((self.run_dir / "handles.json").read_text())
        self.deformer = ShapeDeformer(self.nominal, hs.handles, hs.anchors, **self.plan.deformer.options)
        ev = self.plan.evaluator
        self.collision = make_collision(ev.get("collision", "fast"), self.nominal, ev.get("coacd") or None,
                                        ev.get("cache_dir"), ev.get("max_hull_vertices", 64))
        self.task, self.policy = self.plan.task, self.plan.policy
        self._session, self._loaded = None, None
        from grt.evaluators.worker_env import worker_path

        self._child = None if here or not worker_path(self.policy) else _ChildReplayer(self.run_dir)

    def _nominal(self, saved):
        """The run's own nominal mesh: prepared again from its object spec when that gives the journal's
        hash (bit for bit the mesh the search deformed), else ``nominal.obj`` (the same to ~1e-15 m, which
        the deformation carries to ~1e-13 m: outcomes agree, the journal's 1e-9-rounded hashes may not)."""
        from grt.geometry.mesh import load_mesh, mesh_hash

        want = (self.records.get((0, 0)) or {}).get("mesh_hash")
        try:
            from grt.tasks import task_object

            plan = self.plan
            mesh = load_mesh(task_object(plan.task, plan.object, plan.cache_dir), scale=plan.object_scale,
                             settings=plan.mesh)
            if want and mesh_hash(mesh.vertices, mesh.faces) == want and len(mesh.vertices) == len(saved.vertices):
                return mesh
        except Exception as exc:  # noqa: BLE001 - a moved mesh file: nominal.obj is the record
            log.info("replay: the object %s does not load again (%s); using nominal.obj", self.plan.object, exc)
        return saved

    def record(self, iteration: int, candidate: int) -> dict:
        rec = self.records.get((iteration, candidate))
        if rec is None:
            raise ReplayError(f"it{iteration}_c{candidate} is not in {self.run_dir / 'journal.jsonl'}; the report's "
                              "trial table names the candidates (it<t>_c<i>, nominal)")
        return rec

    def mesh(self, iteration: int, candidate: int):
        """The candidate's mesh as the search made it (its hash checked against the journal's)."""
        from grt.geometry.mesh import mesh_hash

        rec = self.record(iteration, candidate)
        if rec.get("valid") is False:
            raise ReplayError(f"it{iteration}_c{candidate} was refused as implausible and never simulated: no "
                              "trial to replay")
        mesh = self.nominal if iteration == 0 else self.deformer.meshes(np.asarray(rec["theta"], np.float64))[0]
        got = mesh_hash(mesh.vertices, mesh.faces)
        if rec.get("mesh_hash") and got != rec["mesh_hash"] and iteration == 0:
            raise ReplayError(f"it{iteration}_c{candidate}: the rebuilt mesh (hash {got}) is not the one the search "
                              f"simulated ({rec['mesh_hash']}); the run's nominal.obj or handles.json changed, or "
                              "the deformation code did: replay with the commit in its summary.json")
        if rec.get("mesh_hash") and got != rec["mesh_hash"]:
            note = (f"it{iteration}_c{candidate}: mesh hash {got} is not the journal's {rec['mesh_hash']} (the "
                    "object was rebuilt from nominal.obj, equal to ~1e-13 m; the hash rounds to 1e-9 m)")
            log.warning("replay: %s", note)
            self.notes.append(note)
        return mesh

    def session(self):
        if self._session is None:
            from grt.evaluators.pool import build_session

            with _one_thread():
                self._session = build_session(self.task, self.policy)
        return self._session

    def run(self, iteration: int, candidate: int, seed: int, video: Path | None = None) -> dict:
        """Run one trial; returns ``{candidate, seed, outcome, mode, score, journal_outcome, ...}``."""
        if self._child is not None:
            out, notes = self._child.run(iteration, candidate, seed, video)
            self.notes.extend(n for n in notes if n not in self.notes)
            return out
        rec = self.record(iteration, candidate)
        trial = next((t for t in rec.get("trials", []) if int(t["seed"]) == int(seed)), None)
        if trial is None:
            seeds = [t["seed"] for t in rec.get("trials", [])]
            raise ReplayError(f"seed {seed} is not a trial of it{iteration}_c{candidate}; its seeds: "
                              f"{', '.join(map(str, seeds[:8]))}{' ...' if len(seeds) > 8 else ''}")
        session = self.session()
        key = (iteration, candidate)
        if self._loaded != key:
            mesh = self.mesh(iteration, candidate)
            session.load_object(mesh, self.collision.parts(mesh))
            self._loaded = key
        start = time.perf_counter()
        frames: list[np.ndarray] = []
        steps = [0]
        with _one_thread(), _filming(session, steps=steps):
            outcome = session.run_trial(int(seed))
        stride = max(1, math.ceil(steps[0] / MAX_FRAMES))
        if video:  # filmed again, knowing its length: ~MAX_FRAMES frames (an outcome is a function of mesh and seed)
            framing = getattr(session.env.unwrapped, "video_camera", None)  # the grasp env's: on the nominal object
            camera = framing(self.nominal) if framing is not None else {}
            with _one_thread(), _filming(session, frames, stride=stride, steps=[0], camera=camera):
                filmed = session.run_trial(int(seed))
            if (filmed.mode, filmed.score) != (outcome.mode, outcome.score):
                self.notes.append(f"the filmed run ended {filmed.mode}, the unfilmed one {outcome.mode}")
        name = "nominal" if iteration == 0 else f"it{iteration}_c{candidate}"
        out = {"candidate": name, "seed": int(seed), "outcome": outcome.mode, "score": outcome.score,
               "journal_outcome": trial.get("mode"), "journal_score": trial.get("score"),
               "match": outcome.mode == trial.get("mode") and outcome.score == trial.get("score"),
               "wall_s": round(time.perf_counter() - start, 2)}
        if video:
            out["video"] = str(write_video(frames, Path(video), fps=max(1, round(VIDEO_FPS / stride))))
            out["frames"] = len(frames)
        return out

    def close(self) -> None:
        if self._child is not None:
            self._child.close()
            self._child = None
        if self._session is not None:
            self._session.close()
            self._session = None


class _ChildReplayer:
    """A :class:`RunReplayer` in a spawned process whose import path starts with the run's policy's
    ``worker_path`` (:mod:`grt.evaluators.worker_env`): the trials, and their filming, run where the run's
    simulator workers ran them (ManiSkill's motion planners need numpy 1.26, this process has numpy 2)."""

    def __init__(self, run_dir: Path):
        import multiprocessing as mp

        from grt.config import saved_plan
        from grt.evaluators.worker_env import spawn_path, worker_path
        from grt.runfolder.record import load_run_config

        ctx = mp.get_context("spawn")
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=_replay_child, args=(str(run_dir), child), daemon=True)
        with spawn_path(worker_path(saved_plan(load_run_config(run_dir), Path(run_dir)).policy)):
            self.proc.start()
        child.close()

    def run(self, iteration: int, candidate: int, seed: int, video: Path | None) -> tuple[dict, list[str]]:
        self.conn.send((iteration, candidate, seed, None if video is None else str(video)))
        try:
            kind, value, notes = self.conn.recv()
        except EOFError:
            raise RuntimeError(f"the replay process died (exit code {self.proc.exitcode})") from None
        if kind == "user":
            raise ReplayError(value)
        if kind == "error":
            raise RuntimeError(value)
        return value, notes

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.conn.send(None)
        self.proc.join(timeout=30)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        self.conn.close()


def _replay_child(run_dir: str, conn) -> None:
    """The child of :class:`_ChildReplayer`: one :class:`RunReplayer`, one trial per message until ``None``."""
    from grt.evaluators.worker_env import accept_numpy2_pickles

    accept_numpy2_pickles()
    replayer = None
    try:
        replayer = RunReplayer(Path(run_dir), here=True)
        while (job := conn.recv()) is not None:
            iteration, candidate, seed, video = job
            try:
                out = replayer.run(iteration, candidate, seed, video=None if video is None else Path(video))
                conn.send(("ok", out, list(replayer.notes)))
            except UserError as exc:
                conn.send(("user", str(exc), []))
            except Exception as exc:  # noqa: BLE001 - said in the parent, as an error of this process would be
                conn.send(("error", f"{type(exc).__name__}: {exc}", []))
    except (EOFError, OSError):
        pass
    finally:
        if replayer is not None:
            replayer.close()


@contextlib.contextmanager
def _one_thread():
    """The thread limits of a search's worker (``threads: 1``), so numerics match the run's."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - scikit-learn/numpy bring it
        yield
        return
    with threadpool_limits(1):
        yield


@contextlib.contextmanager
def _filming(session, frames: list | None = None, stride: int = 1, steps: list | None = None,
             camera: dict | None = None):
    """Count the env steps (``steps[0]``) and, with ``frames``, grab a frame of the task's render camera after
    every ``stride``-th step (``camera``: its settings for this film, e.g. the grasp env's framing of the
    nominal object, :meth:`grt.tasks.grasp_env.GraspEnv.video_camera`)."""
    env = session.env
    step = env.step
    count = steps if steps is not None else [0]
    raw = env.unwrapped
    custom = raw._custom_human_render_camera_configs
    if frames is not None:
        # The trial rebuilds its scene first, which re-reads the render camera's settings: film at VIDEO_SIZE
        # (lavapipe renders 512 x 512 at ~5 frames/s; 320 x 320 keeps a replay within seconds).
        raw._custom_human_render_camera_configs = {**(custom or {}), **(camera or {}), "width": VIDEO_SIZE,
                                                   "height": VIDEO_SIZE}

    def filmed(action):
        result = step(action)
        if frames is not None and count[0] % stride == 0:
            image = env.unwrapped.render_rgb_array()
            image = image.cpu().numpy() if hasattr(image, "cpu") else np.asarray(image)
            frames.append(np.asarray(image[0] if image.ndim == 4 else image, dtype=np.uint8))
        count[0] += 1
        return result

    env.step = filmed
    try:
        yield
    finally:
        del env.step  # the instance attribute: the class's step again
        raw._custom_human_render_camera_configs = custom


def write_video(frames: list[np.ndarray], path: Path, fps: int = VIDEO_FPS) -> Path:
    """Encode frames as MP4/H.264 (imageio-ffmpeg), lowering the quality until the file is <= 2 MB."""
    import imageio.v2 as imageio

    if not frames:
        raise ReplayError("the trial stepped no simulation (it ended before acting): nothing to film")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp.mp4")
    for crf in (28, 34, 40):
        writer = imageio.get_writer(str(tmp), fps=fps, codec="libx264", quality=None, macro_block_size=16,
                                    ffmpeg_params=["-crf", str(crf), "-preset", "veryfast", "-pix_fmt", "yuv420p",
                                                   "-movflags", "+faststart"], ffmpeg_log_level="error")
        for f in frames:
            writer.append_data(f)
        writer.close()
        if tmp.stat().st_size <= MAX_VIDEO_BYTES:
            break
    os.replace(tmp, path)
    return path


def render_videos(run_dir: Path, summary: dict, count: int) -> dict:
    """Film the nominal object and each of the top ``count`` CrashShapes on one failing seed of that shape
    (its first failing trial; its first trial if none failed), into ``videos/`` with ``videos.json``.

    Never raises for a missing renderer: the index says why there are no videos.
    """
    run_dir = Path(run_dir)
    out = run_dir / "videos"
    out.mkdir(exist_ok=True)
    index: dict = {"pairs": [], "camera": f"the task's render camera (grasp: framed on the nominal object and the room "
                   f"its lift and shake need, the same for both clips), {VIDEO_SIZE} x {VIDEO_SIZE}, about one frame "
                   "per 0.1 s of the episode (every n-th control step, played in real time)"}
    start = time.perf_counter()
    problem = renderer_problem()
    shapes = (summary.get("crashshapes") or [])[:count]
    if problem:
        index["skipped"] = problem
    elif not shapes:
        index["skipped"] = "the run saved no CrashShape"
    else:
        replayer, filmed = RunReplayer(run_dir), {}
        try:
            for shape in shapes:
                it, c = shape["iteration"], shape["candidate"]
                trials = replayer.record(it, c).get("trials", [])
                failing = next((t for t in trials if t.get("mode") != "success"), trials[0] if trials else None)
                if failing is None:
                    continue
                seed = int(failing["seed"])
                pair = {"title": f"rank {shape['rank']}: it{it}_c{c}", "seed": seed, "clips": []}
                for label, (i, j) in (("nominal", (0, 0)), (f"CrashShape it{it}_c{c}", (it, c))):
                    name = f"{'nominal' if i == 0 else f'it{i}_c{j}'}_seed{seed}.mp4"
                    if name not in filmed:  # two shapes failing on one seed share the nominal's clip
                        res = replayer.run(i, j, seed, video=out / name)
                        filmed[name] = {"file": name, "mode": res["outcome"], "journal_mode": res["journal_outcome"],
                                        "match": res["match"], "frames": res["frames"],
                                        "bytes": (out / name).stat().st_size}
                    pair["clips"].append({**filmed[name], "label": label})
                index["pairs"].append(pair)
        except Exception as exc:  # a video is a nicety: the run's results stand; say why in one line
            index["skipped"] = f"filming stopped: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
            log.warning("videos: %s", index["skipped"])
        finally:
            replayer.close()
    index["wall_s"] = round(time.perf_counter() - start, 1)
    write_text_atomic(out / "videos.json", json.dumps(index, indent=2))
    return index
