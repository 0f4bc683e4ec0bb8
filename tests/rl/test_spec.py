"""A training's settings as the library reads them (:class:`grt.rl.spec.PolicyTrainingSpec`): made of
``python -m grt.train``'s composed config, plain; the whole training through the command is
tests/cli/test_train_resume.py's."""

from __future__ import annotations

import pytest

from grt.config import plain
from grt.geometry.prepare import MeshError, MeshSettings
from grt.rl.spec import PolicyTrainingSpec
from tests.runner.conftest import compose_run


def spec_of(*overrides: str) -> PolicyTrainingSpec:
    cfg = compose_run(["paths.output_dir=/runs/train", *overrides], config_name="train_policy")
    return PolicyTrainingSpec.of(plain(cfg))  # what grt.cli.train passes


def test_the_spec_holds_the_apps_settings():
    spec = spec_of("task=drawer", "train=drawer_state", "eval_trials=0", "init_checkpoint=/ckpt/start.pt")
    assert (spec.task["name"], spec.name, spec.train["iterations"]) == ("drawer", "drawer_state", 1500)
    assert spec.object == str(spec.task["object"]) and spec.mesh is None and spec.eval_trials == 0
    assert spec.init_checkpoint == "/ckpt/start.pt" and not spec.resume and spec.logger["_target_"]
    assert spec.config["train"] == spec.train and spec.config["paths"]["output_dir"] == "/runs/train"
    spec.train["name"] = "changed"  # the logger's config is its own copy
    assert spec.config["train"]["name"] == "drawer_state"
    with pytest.raises(AttributeError):
        spec.eval_trials = 3


def test_a_mesh_section_is_parsed_once_and_a_key_it_lacks_is_one_line():
    assert spec_of("+mesh.remesh=on").mesh == MeshSettings(remesh="on")
    with pytest.raises(MeshError, match="mesh.fidelity is not a mesh setting"):
        spec_of("+mesh.fidelity=2")
