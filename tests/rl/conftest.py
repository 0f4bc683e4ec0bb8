"""Fixtures of the learning tests: the tiny reach task, its config and a shape."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

HERE = Path(__file__).parent


@pytest.fixture
def reach_task():
    """The reach task's config (``task["session"]`` builds :class:`_reach_task.ReachSession`)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.syspath_prepend(str(HERE))  # spawned workers inherit sys.path
        yield {"name": "reach", "session": {"_target_": "_reach_task.ReachSession"}}


@pytest.fixture
def box_shape():
    from grt.rl.vec_env import Shape

    box = trimesh.creation.box([0.06, 0.03, 0.05])
    return Shape.of(box, [np.asarray(box.vertices)], "box")


TRAIN_CFG = {
    "seed": 0, "num_steps_per_env": 16,
    "obs_groups": {"actor": ["state"], "critic": ["state"]},
    "actor": {"class_name": "MLPModel", "hidden_dims": [32, 32], "activation": "elu", "obs_normalization": True,
              "distribution_cfg": {"class_name": "GaussianDistribution", "init_std": 0.5, "std_type": "scalar"}},
    "critic": {"class_name": "MLPModel", "hidden_dims": [32, 32], "activation": "elu", "obs_normalization": True},
    "algorithm": {"class_name": "PPO", "num_learning_epochs": 4, "num_mini_batches": 2, "learning_rate": 1e-3,
                  "schedule": "fixed", "entropy_coef": 0.0, "gamma": 0.95},
}


@pytest.fixture
def train_cfg():
    import copy

    return copy.deepcopy(TRAIN_CFG)
