"""``python -m grt.train`` (``grt-train``): train a task's policy with PPO (rsl-rl); a Hydra app.

    python -m grt.train task=insertion train=insertion_state
    python -m grt.train task=insertion train=insertion_pcd
    python -m grt.train resume=outputs/train/insertion/insertion_state/<time>
    python -m grt.train task=insertion train=insertion_state \
        train.export=grt/policies/checkpoints/insertion_state.pt train.overwrite_shipped=true

The trained policy is the run folder's ``policy.pt``; ``train.export=PATH`` copies it elsewhere too, and
replacing a shipped policy (under ``grt/policies/checkpoints``) needs ``train.overwrite_shipped=true``.

The work and the run folder's files: :func:`grt.rl.policy_training.train_policy`.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

import grt.config  # noqa: F401 - registers schemas and resolvers
from grt.cli._common import CONF_DIR, exit_on_user_error, find_user_error, run_cli
from grt.rl.policy_training import train_policy
from grt.runfolder import ResumeError, discard_new, resume_or  # also registers the resume_or resolver


@hydra.main(config_path=CONF_DIR, config_name="train_policy", version_base="1.3")
def main(cfg: DictConfig) -> float:
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    with exit_on_user_error():
        try:
            if cfg.resume:  # also when hydra.run.dir is given, which the resume_or resolver then never sees
                resume = Path(resume_or(cfg.resume, ""))
                if resume.resolve() != out_dir.resolve():
                    raise ResumeError(f"resume={cfg.resume} with hydra.run.dir={out_dir}: a training goes on in its "
                                      f"own folder; give resume={cfg.resume} alone")
            result = train_policy(cfg, out_dir)
        except Exception as exc:
            found = find_user_error(exc)
            if found is None:
                raise
            removed = discard_new(out_dir)  # refused before it saved anything: no folder left behind
            print(f"error: {found}" + (f" ({removed})" if removed else ""), file=sys.stderr)
            raise SystemExit(2) from None
    print(f"trained {result['iterations']} iterations ({result['steps']} steps) in {result['wall_s']:.0f} s; "
          f"best training success {result['best_success']:.2f}; files in {out_dir}")
    ev = result.get("evaluation")
    if ev:
        print(f"evaluation: {cfg.task.score} {ev['score']:.4g} (success {ev['success_rate']:.3f}) over "
              f"{ev['trials']} trials {ev['outcomes']}")
    return float(result["best_success"])


def cli() -> None:
    """The console script ``grt-train``."""
    run_cli(main)
