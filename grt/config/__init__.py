"""The Hydra config, and the plan made of it: with the apps (:mod:`grt.cli`), the only code that reads Hydra.

- :mod:`grt.config.schema`: the budget's schema (made from :class:`grt.plan.Budget`) and the resolvers,
  registered before Hydra composes;
- :mod:`grt.config.checks`: :func:`validate`, each app's first step, refuses a bad value before anything is
  written;
- :mod:`grt.config.planning`: :func:`make_plan`, a red-team run's settings parsed once into the typed
  :class:`grt.plan.RunPlan` that the library reads;
- :mod:`grt.config.records`: config files and command lines as plain data, for the run folders.
"""

from grt.config.checks import READ_IF_GIVEN, SettingError, check_added_keys, check_sections, validate
from grt.config.planning import make_plan, saved_plan, without_secrets
from grt.config.schema import (
    BudgetSchema,
    ConfigError,
    add_resolver,
    budget_hint,
    check_budget,
    plain,
    register,
    unknown_budget_key,
)
from grt.plan import (  # the rules' vocabulary, for the apps' own settings
    BOOLEAN,
    BUDGET_KEYS,
    POSITIVE,
    POSITIVE_OR_NULL,
    RISK,
    Rule,
    at_least,
    object_folder,
    object_name,
)

__all__ = ["BOOLEAN", "BUDGET_KEYS", "POSITIVE", "POSITIVE_OR_NULL", "READ_IF_GIVEN", "RISK", "BudgetSchema",
           "ConfigError", "Rule", "SettingError", "add_resolver", "at_least", "budget_hint", "check_added_keys",
           "check_budget", "check_sections", "make_plan", "object_folder", "object_name", "plain", "register", "saved_plan",
           "unknown_budget_key", "validate", "without_secrets"]
