"""Run loggers (config group ``logger``). The run folder is always the source of truth; a logger
mirrors it elsewhere. No secret (API key) is ever passed to a logger or written to outputs."""

from __future__ import annotations

from pathlib import Path


class NullLogger:
    """Logs nothing (the default)."""

    def start(self, run_dir: Path, name: str, config: dict) -> None:
        """Begin a run; ``config`` is the resolved config as plain containers."""

    def log_iteration(self, iteration: int, metrics: dict) -> None:
        """Per-iteration scalars (best score, degradation, evaluations)."""

    def log_images(self, images: dict[str, Path]) -> None:
        """Pictures by key (curve, CrashShapes)."""

    def log_summary(self, summary: dict) -> None:
        """Final metrics."""

    def log_report(self, run_dir: Path, summary: dict, videos: dict | None) -> None:
        """What ``report.html`` shows: the CrashShapes, their table and the videos (``videos/videos.json``)."""

    def finish(self) -> None:
        """Close the run (also on failure)."""


class WandbLogger(NullLogger):
    """Weights & Biases logger.

    Args:
        project: W&B project.
        entity: W&B entity (team/user), or ``None`` for the default.
        mode: ``"disabled"`` (default: nothing happens), ``"offline"`` (files under the run folder,
            no network; ``wandb sync`` them later) or ``"online"`` (needs ``WANDB_API_KEY``).
        tags: run tags.
    """

    def __init__(self, project: str = "grt", entity: str | None = None, mode: str = "disabled",
                 tags: list[str] | None = None):
        if mode not in ("disabled", "offline", "online"):
            raise ValueError(f"logger.mode must be disabled, offline or online, got {mode!r}")
        self.project, self.entity, self.mode, self.tags = project, entity, mode, list(tags or [])
        self.run = None

    def start(self, run_dir: Path, name: str, config: dict) -> None:
        import wandb

        self.run = wandb.init(project=self.project, entity=self.entity, mode=self.mode, dir=str(run_dir),
                              name=name, tags=self.tags, config=config, reinit=True)

    def log_iteration(self, iteration: int, metrics: dict) -> None:
        if self.run is not None:
            self.run.log({"iteration": iteration, **metrics}, step=iteration)

    def log_images(self, images: dict[str, Path]) -> None:
        if self.run is not None:
            import wandb

            self.run.log({k: wandb.Image(str(p)) for k, p in images.items() if Path(p).exists()})

    def log_summary(self, summary: dict) -> None:
        if self.run is not None:
            for k, v in summary.items():
                if isinstance(v, (int, float, str, bool)) or v is None:
                    self.run.summary[k] = v

    def log_report(self, run_dir: Path, summary: dict, videos: dict | None) -> None:
        """The CrashShapes as 3D objects (their printable STL files), one table row per CrashShape (scores,
        fresh-episode confirmation, its trials' failure modes against the nominal's) and the replayed
        trials' videos, as ``report.html`` shows them."""
        if self.run is None:
            return
        import wandb

        run_dir = Path(run_dir)
        records = {}
        journal = run_dir / "journal.jsonl"
        if journal.is_file():
            import json

            for line in journal.read_text().splitlines():
                try:
                    rec = json.loads(line)
                except ValueError:
                    continue
                records[(rec.get("iteration"), rec.get("candidate"))] = rec
        modes = lambda rec: ", ".join(f"{m} {n}" for m, n in sorted((rec or {}).get("outcomes", {}).items()))  # noqa: E731
        fresh = {(c["iteration"], c["candidate"]): c for c in (summary.get("confirm") or {}).get("shapes", [])}
        table = wandb.Table(columns=["rank", "candidate", "score", "fresh_score", "p_holm", "modes", "nominal_modes",
                                     "shape"])
        logged: dict = {}
        for shape in summary.get("crashshapes") or []:
            key = (shape["iteration"], shape["candidate"])
            path = run_dir / shape["file"]
            obj = wandb.Object3D(str(path)) if path.is_file() else None
            if obj is not None:
                logged[f"crashshape/rank{shape['rank']}"] = obj
            c = fresh.get(key, {})
            table.add_data(shape["rank"], f"it{key[0]}_c{key[1]}", shape["score"], c.get("score"), c.get("p_holm"),
                           modes(records.get(key)), modes(records.get((0, 0))), _displacement_cloud(run_dir, shape))
        logged["crashshapes"] = table
        for pair in (videos or {}).get("pairs", []):
            for clip in pair.get("clips", []):
                path = run_dir / "videos" / clip["file"]
                if path.is_file():
                    logged[f"video/{Path(clip['file']).stem}"] = wandb.Video(
                        str(path), format="mp4", caption=f"{pair['title']}, seed {pair['seed']}: {clip['label']} "
                                                         f"{clip['mode']}")
        self.run.log(logged)

    def finish(self) -> None:
        if self.run is not None:
            self.run.finish()
            self.run = None


def _displacement_cloud(run_dir: Path, shape: dict):
    """A CrashShape's vertices coloured by their displacement from ``nominal.obj`` (dark: none, yellow: the
    largest), as a W&B point cloud (W&B tables take point clouds, not meshes); ``None`` without the files."""
    import numpy as np
    import trimesh
    import wandb

    obj, nominal = run_dir / shape["file"].replace(".stl", ".obj"), run_dir / "nominal.obj"
    if not obj.is_file() or not nominal.is_file():
        return None
    v = np.asarray(trimesh.load(obj, process=False, force="mesh").vertices)
    v0 = np.asarray(trimesh.load(nominal, process=False, force="mesh").vertices)
    if v.shape != v0.shape:
        return None
    d = np.linalg.norm(v - v0, axis=1)
    t = d / (d.max() or 1.0)
    rgb = np.stack([68 + 185 * t, 1 + 230 * t, 84 - 50 * t], axis=1)  # viridis' ends
    return wandb.Object3D(np.hstack([v, rgb]))
