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

    def finish(self) -> None:
        if self.run is not None:
            self.run.finish()
            self.run = None
