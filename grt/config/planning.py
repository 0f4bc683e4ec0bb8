"""The run as a plan: :func:`make_plan` turns a red-team run's config into a :class:`grt.plan.RunPlan`.

The config is read here once: the budget, the task's score settings, the deformer, the object and its mesh
settings, the classes to build (plain ``_target_`` nodes), the run's config-group options and command line
(Hydra's, when it runs), and the resolved config as the run folder and loggers keep it
(:func:`without_secrets`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from grt.agreement import SwapCheckSettings
from grt.config.schema import plain
from grt.geometry.prepare import MeshSettings
from grt.plan import Budget, DeformerPlan, RunPlan


def make_plan(cfg, choices: Mapping | None = None) -> RunPlan:
    """The plan of one red-team run: its config parsed once (:mod:`grt.plan`).

    Args:
        cfg: the composed root config of ``grt.run`` (or the same as a plain mapping, e.g. a resumed run's own
            config, :func:`grt.runfolder.resume.own_config`).
        choices: the run's config-group options; by default the running Hydra app's, else each group's
            ``_target_`` module name (a test calling :func:`grt.runner.run` without Hydra).

    Raises:
        ScoreConfigError: a bad ``task.ci``, ``task.nominal_floor`` or ``task.crash_margin``.
    """
    cfg = cfg if isinstance(cfg, DictConfig) else OmegaConf.create(cfg)
    return _plan(cfg, Path(cfg.resume or cfg.paths.output_dir), bool(cfg.resume),
                 dict(choices) if choices is not None else _choices(cfg), without_secrets(cfg), _command_line())


def saved_plan(config: Mapping, run_dir: Path, choices: Mapping | None = None) -> RunPlan:
    """The plan a run folder's saved config gives (:func:`grt.runfolder.record.load_run_config`), for what reads
    a finished or stopped run (a replay, a blue-team study, a resume's check that nothing is left to do).

    Its ``config`` is the saved one as written (an old folder's may hold interpolations of Hydra's that do not
    resolve outside the run, ``${hydra:...}``), its ``record`` empty; ``choices``: the run's config-group
    options (its record's), else each group's ``_target_`` module name.
    """
    cfg = OmegaConf.create(dict(config))
    return _plan(cfg, Path(run_dir), False, dict(choices) if choices is not None else _choices(cfg, hydra=False),
                 OmegaConf.to_container(cfg, resolve=False), {"overrides": [], "choices": {}})


def _plan(cfg: DictConfig, run_dir: Path, resume: bool, choices: dict, config: dict, record: dict) -> RunPlan:
    score, floor, margin = RunPlan.task_settings(cfg.task)
    return RunPlan(
        run_dir=run_dir, resume=resume, object=str(cfg.object),
        object_scale=float(cfg.get("object_scale", 1.0) or 1.0),
        cache_dir=str(OmegaConf.select(cfg, "paths.cache_dir", default="~/.cache/grt")),
        mesh=MeshSettings.from_config(cfg.get("mesh")), task=plain(cfg.task), policy=plain(cfg.policy),
        **{key: plain(cfg[key]) if cfg.get(key) is not None else {} for key in _BUILT},
        deformer=DeformerPlan.of(cfg.get("deformer") or {}), budget=Budget.of(cfg.budget), score=score,
        nominal_floor=floor, crash_margin=margin,
        report_videos=int(OmegaConf.select(cfg, "report.videos", default=0) or 0),
        swap_check=SwapCheckSettings.from_config(plain(cfg.swap_check) if cfg.get("swap_check") is not None else None),
        choices=choices, config=config, record=record)


#: The ``_target_`` nodes a run builds at run time (selector, optimizer, evaluator, logger).
_BUILT = ("selector", "optimizer", "evaluator", "logger")


def _choices(cfg: DictConfig, hydra: bool = True) -> dict:
    """The config-group options of a run: the running Hydra app's (``hydra``), else each built group's and the
    policy's ``_target_`` module name, which is the option's by convention."""
    from hydra.core.hydra_config import HydraConfig

    found = {str(k): v for k, v in plain(HydraConfig.get().runtime.choices).items()
             if not (k == "hydra" or str(k).startswith("hydra/"))} if hydra and HydraConfig.initialized() else {}
    for group in (*_BUILT, "policy"):
        if group not in found and isinstance(cfg.get(group), DictConfig) and "_target_" in cfg[group]:
            found[group] = str(cfg[group]["_target_"]).rsplit(".", 2)[-2]
    return found


def _command_line() -> dict:
    """The running Hydra app's command line as a run's record keeps it: its overrides (``resume=`` left out)
    and its config-group options (``hydra/*`` left out); empty outside Hydra."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.core.override_parser.overrides_parser import OverridesParser

    if not HydraConfig.initialized():
        return {"overrides": [], "choices": {}}
    hydra_cfg = HydraConfig.get()
    parser = OverridesParser.create()
    return {"overrides": [o for o in hydra_cfg.overrides.task if parser.parse_override(o).key_or_group != "resume"],
            "choices": {k: v for k, v in plain(hydra_cfg.runtime.choices).items()
                        if not (k == "hydra" or k.startswith(("hydra.", "hydra/")))}}


def without_secrets(cfg: DictConfig) -> dict:
    """The resolved config, but a served policy's shared secret (``policy.token``) as given — its
    ``${oc.env:GRT_POLICY_TOKEN,null}`` — never its value: what run folders and loggers may keep."""
    config = plain(cfg)
    if isinstance(config.get("policy"), dict) and config["policy"].get("token") is not None:
        config["policy"]["token"] = OmegaConf.to_container(cfg.policy, resolve=False)["token"]
    return config
