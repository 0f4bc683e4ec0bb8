"""A policy training as a plan: the settings of ``python -m grt.train`` (``conf/train_policy.yaml``), parsed once.

The app (:mod:`grt.cli.train`) makes a :class:`PolicyTrainingSpec` of its composed config before torch is imported;
:func:`grt.rl.policy_training.train_policy` reads the spec, never the config. The training config itself
(``train``, a ``conf/train`` file) stays plain data: it is the rsl-rl runner's config and what every checkpoint
keeps (:func:`grt.rl.train.grt_config`).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass

from grt.geometry.prepare import MeshSettings


@dataclass(frozen=True)
class PolicyTrainingSpec:
    """One ``python -m grt.train`` training.

    Attributes:
        task: the task config, plain and resolved (what sessions and workers take); its ``name`` and ``score``.
        train: the training config (``conf/train/<name>.yaml``), plain: PPO's and the runner's settings,
            ``name``, ``iterations``, ``workers``, ``bc`` (a warm start, its ``expert`` a ``_target_`` node),
            ``validation``, ``export`` ...
        object: the object trained on (a built-in name or a mesh file).
        cache_dir: GRT's cache (collision parts, ManiSkill actors).
        mesh: how the object's mesh is prepared (``None``: no ``mesh`` section, the loader's defaults).
        init_checkpoint: start from these weights (fine-tuning) instead of from scratch.
        eval_trials: seeded evaluation episodes of the exported policy (0: none).
        resume: the training goes on in its own folder.
        logger: the ``logger`` node (``_target_``, plain), built with :func:`grt.targets.build`.
        config: the whole resolved config, as the logger keeps it.
    """

    task: dict
    train: dict
    object: str
    cache_dir: str
    mesh: MeshSettings | None
    init_checkpoint: str | None
    eval_trials: int
    resume: bool
    logger: dict
    config: dict

    @classmethod
    def of(cls, config: Mapping) -> PolicyTrainingSpec:
        """The spec of the app's root config, plain and resolved (:func:`grt.config.plain`).

        Raises:
            MeshError: a ``mesh`` key that is no mesh setting.
        """
        init = config.get("init_checkpoint")
        # copies: the logger's config stays as given, whatever the training does with its task and train dicts
        return cls(task=copy.deepcopy(dict(config["task"])), train=copy.deepcopy(dict(config["train"])),
                   object=str(config["object"]),
                   cache_dir=str(config["paths"]["cache_dir"]),
                   mesh=MeshSettings.from_config(config["mesh"]) if config.get("mesh") else None,
                   init_checkpoint=None if init is None else str(init), eval_trials=int(config.get("eval_trials") or 0),
                   resume=bool(config.get("resume")), logger=dict(config["logger"]), config=copy.deepcopy(dict(config)))

    @property
    def name(self) -> str:
        """The training config's name (``train.name``: ``insertion_state`` ...)."""
        return str(self.train["name"])
