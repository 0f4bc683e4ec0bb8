"""The blue-team study's settings as the library reads them (:class:`grt.blueteam.spec.StudySpec`): made of the
app's composed config, checked once, one line naming the setting for a bad value. The command's own refusals
are tests/blueteam/test_blueteam.py's (``test_settings_out_of_range_are_one_line_before_any_simulation``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from grt.agreement import SwapCheckError
from grt.blueteam.spec import BlueTeamError, StudySpec
from grt.cli.blueteam import study_spec
from tests.runner.conftest import compose_run


def spec_of(*overrides: str) -> StudySpec:
    return study_spec(compose_run(["run=/runs/one", *overrides], config_name="blueteam"))


def test_the_spec_holds_the_apps_settings_typed():
    spec = spec_of("workers=3", "blueteam.crashshapes=[it2_c5,it3_c1]", "blueteam.val_trials_nominal=null",
                   "blueteam.val_trials=6", "evaluator=ray", "evaluator.address=auto", "swap_check.accept=true")
    assert spec.run == Path("/runs/one") and spec.workers == 3 and spec.crashshapes == ("it2_c5", "it3_c1")
    assert spec.val_trials_nominal == 6  # null: the CrashShapes' number
    assert spec.evaluator["_target_"].endswith("RayEvaluator") and spec.evaluator["workers"] == 3  # resolved
    assert spec.swap_check.accept and spec.rered and spec.nominal_guard == "fisher"
    assert (spec.confirm.candidates, spec.anchor.updates, spec.heldout.nearby) == (3, 0, 2)
    assert spec_of().crashshapes == "top1" and spec_of().val_trials_nominal == 32
    with pytest.raises(AttributeError):
        spec.iterations = 1  # frozen: what the study reads is what was checked


@pytest.mark.parametrize(("override", "words"), [
    ("blueteam.nominal_guard=strict", "blueteam.nominal_guard='strict' is not a guard: fisher"),
    ("blueteam.failing_below=0", "blueteam.failing_below=0: give a number in (0, 1]"),
    ("blueteam.failing_below=true", "blueteam.failing_below=True: give a number in (0, 1]"),
    ("blueteam.nominal_share=1.0", "blueteam.nominal_share=1.0: give a number in [0, 1)"),
    ("blueteam.val_patience=0", "blueteam.val_patience=0: give an integer >= 1"),
    ("blueteam.eval_trials=2.5", "blueteam.eval_trials=2.5: give an integer >= 1"),
    ("blueteam.confirm.candidates=-1", "blueteam.confirm: candidates=-1, trials=32 cannot confirm"),
    ("blueteam.confirm.trials=0", "blueteam.confirm: candidates=3, trials=0 cannot confirm"),
])
def test_a_bad_setting_is_one_line_naming_it(override, words):
    with pytest.raises(BlueTeamError) as err:
        spec_of(override)
    assert str(err.value).startswith(words) and "\n" not in str(err.value)


def test_confirmation_off_needs_no_trials_and_a_bad_swap_check_is_its_own_line():
    assert spec_of("blueteam.confirm.candidates=0", "blueteam.confirm.trials=0").confirm.candidates == 0
    with pytest.raises(SwapCheckError, match=r"swap_check.min_agreement=2: give a number in \[0, 1\]"):
        spec_of("swap_check.min_agreement=2")
