"""Budget values are checked when the config is composed or validated, before any simulation."""

from __future__ import annotations

import re
from dataclasses import fields

import pytest

from grt.cli._common import exit_on_user_error, find_user_error
from grt.config import BUDGET_KEYS, BudgetSchema, ConfigError, check_budget, validate
from tests.runner.conftest import CONF, compose_run

BUDGETS = sorted(p.stem for p in (CONF / "budget").glob("*.yaml"))


@pytest.mark.parametrize("budget", BUDGETS)
def test_every_budget_option_is_valid(budget):
    cfg = compose_run([f"budget={budget}"])
    assert validate(cfg) is cfg


@pytest.mark.parametrize("override", ["budget.tau=null", "budget.tau=0.01", "budget.population=1",
                                      "budget.seed=0", "budget.sigma=1"])
def test_edge_values_in_range_pass(override):
    validate(compose_run([override]))


@pytest.mark.parametrize(("override", "accepts"), [
    ("budget.population=0", "an integer >= 1"),
    ("budget.iterations=-1", "an integer >= 1"),
    ("budget.trials=0", "an integer >= 1"),
    ("budget.sigma=0", "a finite number > 0"),
    ("budget.sigma=-0.01", "a finite number > 0"),
    ("budget.sigma=nan", "a finite number > 0"),
    ("budget.sigma=inf", "a finite number > 0"),
    ("budget.seed=-1", "an integer >= 0"),
    ("budget.workers=0", "an integer >= 1"),
    ("budget.tau=0", "null (off) or a finite number > 0"),
    ("budget.tau=-0.005", "null (off) or a finite number > 0"),
    ("budget.top_k=0", "an integer >= 1"),
])
def test_out_of_range_values_are_refused_naming_key_and_range(override, accepts):
    key = override.split("=")[0]
    pattern = rf"^{re.escape(key)}=.* is out of range: it must be {re.escape(accepts)}"
    with pytest.raises(ConfigError, match=pattern) as info:
        validate(compose_run([override]))
    assert find_user_error(info.value) is info.value  # one line and exit code 2 in the CLIs
    assert "\n" not in str(info.value)


def test_added_key_is_refused_naming_the_valid_keys():
    cfg = compose_run(["+budget.popsize=3"])  # Hydra's own hint for budget.popsize=3
    with pytest.raises(ConfigError, match="budget.popsize is not a budget setting") as info:
        validate(cfg)
    assert ", ".join(BUDGET_KEYS) in str(info.value)


def test_interpolated_value_of_wrong_type_is_refused():
    cfg = compose_run(["budget=paper", "task.trials=abc"])  # budget.trials: ${task.trials}
    with pytest.raises(ConfigError, match="budget.trials: .*abc.*it must be an integer >= 1"):
        validate(cfg)


def test_optimizer_refusing_the_budget_is_caught_before_simulation():
    with pytest.raises(ConfigError, match=r"budget.population=1 is too small .* at least 2"):
        validate(compose_run(["optimizer=cma_es", "budget.population=1"]))
    validate(compose_run(["optimizer=cma_es", "budget.population=2"]))


def test_plain_mapping_is_checked_too():
    good = {f.name: f.default for f in fields(BudgetSchema)}
    check_budget(good)
    with pytest.raises(ConfigError, match="budget.top_k is not set"):
        check_budget({k: v for k, v in good.items() if k != "top_k"})
    with pytest.raises(ConfigError, match="budget.trials=True is out of range"):
        check_budget({**good, "trials": True})


def test_config_without_budget_passes():
    validate(compose_run(["object=can"], config_name="select"))


@pytest.mark.parametrize(("override", "message"), [
    ("budget.trails=3", "budget.trails is not a budget setting"),
    ("budget.trials=abc", "budget.trials must be an integer >= 1"),
    ("selector=nope", "Available options in 'selector': all, heuristic, manual, vlm"),
])
def test_compose_errors_become_one_line_and_exit_2(override, message, capsys):
    with pytest.raises(SystemExit) as info, exit_on_user_error():
        compose_run([override])  # raises Hydra's ConfigCompositionException
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err
