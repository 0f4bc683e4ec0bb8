"""``python -m grt.train`` (``grt-train``): train a task's policy with PPO (rsl-rl); a Hydra app.

    python -m grt.train task=insertion train=insertion_state
    python -m grt.train task=insertion train=insertion_pcd
    python -m grt.train resume=outputs/train/insertion/insertion_state/<time>
    python -m grt.train resume=outputs/train/insertion/insertion_state/<time> train.iterations=3000
    python -m grt.train task=insertion train=insertion_state \
        train.export=grt/policies/checkpoints/insertion_state.pt train.overwrite_shipped=true

The trained policy is the run folder's ``policy.pt``; ``train.export=PATH`` copies it elsewhere too, and
replacing a shipped policy (under ``grt/policies/checkpoints``) needs ``train.overwrite_shipped=true``.

``resume=DIR`` alone is the whole command to continue a training, with its own config: Hydra's record of
its start, ``DIR/.hydra/config.yaml`` (:func:`grt.runfolder.resume.own_training_config`). :func:`cli` checks DIR
and the command before Hydra starts and hands Hydra the training's own overrides: only the keys of
:data:`grt.runfolder.resume.TRAIN_FREE` may be given with it (``train.iterations`` to train longer — give it again
on each later resume, the record keeps the start's —, ``train.save_interval``, ``train.workers``,
``train.export``, ``train.overwrite_shipped``, ``eval_trials``, ``logger``, ``paths.cache_dir``,
``hydra.*``); any other override that would change the training is one ``error:`` line (exit code 2),
nothing written. Hydra's files of a resume go to ``DIR/.hydra/resume``, so ``DIR/.hydra`` stays the record
of the start. Training goes on from ``DIR/last.pt`` (saved every ``train.save_interval`` iterations); a
folder without one (stopped before its first save) says so in one line and trains from iteration 0. A
folder whose ``.hydra`` a resume rewrote (before this was so) resumes from that record, with the task,
training config and object its ``last.pt`` was trained with.

The work and the run folder's files: :func:`grt.rl.policy_training.train_policy`, which reads the training's
settings as a :class:`grt.rl.spec.PolicyTrainingSpec` made here of the composed config.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from grt.cli._common import CONF_DIR, exit_on_user_error, find_user_error, resumable_cli
from grt.config import plain, validate  # also registers schemas and resolvers
from grt.config.records import parse_overrides
from grt.rl.spec import PolicyTrainingSpec
from grt.runfolder.lock import discard_new
from grt.runfolder.record import TRAIN_RECORD, ResumeError, resume_or
from grt.runfolder.resume import TRAIN_FROM_COMMAND, TRAINING, SavedRun, own_training_config

log = logging.getLogger("grt.train")


@hydra.main(config_path=CONF_DIR, config_name="train_policy", version_base="1.3")
def main(cfg: DictConfig) -> float:
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    with exit_on_user_error():
        try:
            if not cfg.resume:
                validate(cfg)  # every class imports and takes its keys, nothing unread: before any file or torch
            from grt.rl.policy_training import train_policy  # torch: not for a refused command

            if cfg.resume:  # also when hydra.run.dir is given, which the resume_or resolver then never sees
                resume = Path(resume_or(cfg.resume, ""))
                if resume.resolve() != out_dir.resolve():
                    raise ResumeError(f"resume={cfg.resume} with hydra.run.dir={out_dir}: a training goes on in its "
                                      f"own folder; give resume={cfg.resume} alone")
                cfg = resumed_config(cfg, out_dir)
                validate(cfg)  # the training's own config: its classes must still import
            result = train_policy(PolicyTrainingSpec.of(plain(cfg)), out_dir)
        except Exception as exc:
            found = find_user_error(exc)
            if found is None:
                raise
            removed = discard_new(out_dir)  # refused before it saved anything: no folder left behind
            print(f"error: {found}" + (f" ({removed})" if removed else ""), file=sys.stderr)
            raise SystemExit(2) from None
    best, last = result.get("best_success"), result.get("last_success")
    if result.get("nothing_to_train"):
        print(result["nothing_to_train"])
        return float(best if best is not None else last if last is not None else float("nan"))
    print(f"trained {result['iterations']} iterations ({result['steps']} steps) in {result['wall_s']:.0f} s; "
          f"{training_success(result, cfg.train.get('patience'))}; files in {out_dir}")
    ev = result.get("evaluation")
    if ev:
        print(f"evaluation: {cfg.task.score} {ev['score']:.4g} (success {ev['success_rate']:.3f}) over "
              f"{ev['trials']} trials {ev['outcomes']}")
    return float(best if best is not None else last if last is not None else float("nan"))


def training_success(result: dict, patience) -> str:
    """The training's success in words: the best over ``train.patience`` iterations (``best.pt``'s), or, when
    fewer iterations ran, the last ones' (never the -1 the best starts from)."""
    best, last, window = result.get("best_success"), result.get("last_success"), result.get("last_window", 0)
    if best is not None:
        return f"best training success {best:.2f} (over {patience} iterations)"
    if last is None:
        return "no training episode ended, so no training success"
    return (f"training success {last:.2f} over the last {window} iteration{'s' if window != 1 else ''} (no best: "
            f"that needs train.patience={patience} iterations in a row)")


def resumed_config(cfg: DictConfig, out_dir: Path) -> DictConfig:
    """The config a resume of the training in ``out_dir`` trains with: its record, with the free keys of this
    command (:func:`grt.runfolder.resume.own_training_config`); says in one line (console and the run's log)
    when the folder has no ``last.pt`` and training starts at iteration 0.

    A folder whose ``.hydra`` a resume rewrote, before ``grt.train`` kept the start's record, holds the
    record of that resume, which need not be what its ``last.pt`` was trained with (a ``resume=DIR`` alone
    then composed the default task): the task, training config and object come from ``last.pt`` (the free
    ``train.*`` keys this command gives), and a line says so.
    """
    from grt.rl.train import read_checkpoint  # torch: only for a resume

    own = OmegaConf.create(own_training_config(str(cfg.resume), plain(cfg)))
    last = out_dir / "last.pt"
    if not last.exists():
        log.warning("resume=%s: no last.pt there (it is saved every train.save_interval=%s iterations, and "
                    "the training stopped before its first save): nothing was saved yet, so training starts "
                    "at iteration 0", cfg.resume, own.train.save_interval)
    if SavedRun.training(Path(cfg.resume)).started:
        return own
    rewritten = f"{Path(cfg.resume) / TRAIN_RECORD} is the record of an earlier resume (made before grt.train " \
                "kept the record of a training's start)"
    trained = read_checkpoint(last).get("grt", {}) if last.exists() else {}
    if not {"task_cfg", "train_cfg"} <= set(trained):
        log.warning("%s: continuing with that record", rewritten)
        return own
    given = {o.key for o in parse_overrides(list(HydraConfig.get().overrides.task)
                                            if HydraConfig.initialized() else []) or []}
    command = {key.removeprefix("train."): OmegaConf.select(own, key) for key in TRAIN_FROM_COMMAND
               if key.startswith("train.") and key in given}
    own.task = trained["task_cfg"]
    own.train = {**trained["train_cfg"], **command}
    own.object = trained.get("object", own.object)
    log.warning("%s: continuing with the task, training config and object last.pt was trained with (task %s, "
                "train %s, object %s)", rewritten, own.task.name, own.train.name, own.object)
    return own


def cli(argv: list[str] | None = None) -> None:
    """The console script ``grt-train``: a ``resume=`` becomes the folder's own command before Hydra starts."""
    resumable_cli(main, TRAINING, argv)
