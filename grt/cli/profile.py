"""``grt-profile`` (``python -m grt.profile run=RUN`` or ``object=... policy=...``): a robustness profile.

Success against deformation size for one policy and object, random and adversarial, and two margins: the
largest size at which random shapes keep success within the task's crash margin of S0, and the smallest size
at which an adversarial shape (a CrashShape's direction) is confirmed to break the policy. The work is
:func:`grt.profile.command.profile`; this app checks the command and its settings, and writes into Hydra's
folder (``RUN/profile/<time>`` with a run, else ``outputs/profile/<task>/<object>/<policy>/<time>``):
``profile.json``, ``profile.png`` and ``profile.jsonl`` (every evaluation). With a run, the run's
``report.html`` is written again, with the profile in it. A refused command (a run with no CrashShape, of
another task or object, a size ladder empty, not positive or beyond what the deformer keeps plausible) is one
``error:`` line, exit code 2, nothing written. ``resume=DIR`` continues a stopped profile in its folder with its
own config (every evaluation in ``profile.jsonl`` is replayed, not simulated again); with it only
``budget.workers``, the evaluator's keys but its collision ones, ``paths.cache_dir`` and ``hydra.*`` may be
given (:data:`grt.runfolder.PROFILE`).
"""

from __future__ import annotations

import logging
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import DictConfig

from grt.cli._common import CONF_DIR, exit_on_user_error, resumable_cli
from grt.config import ConfigError, add_resolver, at_least, plain, validate

log = logging.getLogger(__name__)
SETTINGS = {"shapes": at_least(1), "trials": at_least(1), "seed": at_least(0), "directions": at_least(0),
            "rounds": at_least(1)}


def profile_folder(run, default: str, stamp: str) -> str:
    """``hydra.run.dir`` of a profile: ``RUN/profile/<time>`` with a run (its report.html finds it there)."""
    return f"{run}/profile/{stamp}" if run not in (None, "", "None", "null") else f"{default}/{stamp}"


add_resolver("profile_folder", profile_folder)


def check_settings(profile: DictConfig) -> None:
    """The ``profile`` section's counts, one line each (the sizes are checked with the object)."""
    for key, rule in SETTINGS.items():
        value = profile.get(key)
        if not rule.check(value):
            raise ConfigError(f"profile.{key}={value!r} is out of range: it must be {rule.accepts}")


def given_keys() -> tuple[str, ...]:
    """The keys (and config groups) this command line set."""
    parsed = OverridesParser.create().parse_overrides(list(HydraConfig.get().overrides.task))
    return tuple(o.key_or_group.lstrip("+~") for o in parsed)


@hydra.main(config_path=CONF_DIR, config_name="profile", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """Hydra entry point (conf/profile.yaml)."""
    with exit_on_user_error():
        validate(cfg, classes=("selector", "evaluator") if cfg.run is None else ("evaluator",))
        check_settings(cfg.profile)
        from grt.profile.command import profile

        out_dir = Path(cfg.resume or HydraConfig.get().runtime.output_dir)
        result = profile(plain(cfg), out_dir, given_keys(), str(HydraConfig.get().runtime.choices.get("policy")))
    print(describe(result, out_dir))
    if cfg.run:
        _report(Path(cfg.run))


def describe(result: dict, out_dir: Path) -> str:
    """The screen: S0, the two margins with their intervals, the files."""
    m = result["margins"]
    rnd = ("below the smallest size measured" if m["random_mm"] is None else
           f"{m['random_mm']:g} mm{' or more (every size kept it)' if m['random_beyond'] else ''}"
           f" (interval {m['random_interval_mm'][0]:g}-{m['random_interval_mm'][1]:g} mm)")
    adv = ("no adversarial shape confirmed at any size" if m["adversarial_mm"] is None else
           f"{m['adversarial_mm']:g} mm (between {m['adversarial_interval_mm'][0]:g} and "
           f"{m['adversarial_interval_mm'][1]:g} mm)")
    if not result["adversarial"]:
        adv = "not measured (no run: random deformations alone)"
    low, high = result["s0_ci95"]
    return "\n".join([
        f"profile: {result['task']} / {result['object']} / {result['policy']}: sizes {result['sizes_mm']} mm "
        f"(largest surface displacement), {result['trials']} fresh episodes each, {result['trials_used']} trials",
        f"  S0 {result['s0']:.3f} [{low:.3f}, {high:.3f}]",
        f"  random margin (success within {result['crash_margin']:.0%} of S0): {rnd}",
        f"  adversarial margin (smallest size confirmed to break it): {adv}",
        f"  files: {out_dir / 'profile.json'}, {out_dir / 'profile.png'}"])


def _report(run_dir: Path) -> None:
    """Write the run's report.html again, now with the profile (a failure is one warning: the profile is saved)."""
    from grt.report.html import write_run_report

    try:
        print(f"  report: {write_run_report(run_dir)} (with this profile)")
    except Exception as exc:  # noqa: BLE001 - the profile is written; say what failed and how to retry
        log.warning("report.html not written again (%s: %s); python -m grt.report %s --html retries it",
                    type(exc).__name__, exc, run_dir)


def cli(argv: list[str] | None = None) -> None:
    """``grt-profile``: a ``resume=`` becomes the profile's own command before Hydra starts; a mistake in the
    command line or the config is one ``error:`` line, exit code 2."""
    from grt.runfolder.resume import PROFILE

    resumable_cli(main, PROFILE, argv)
