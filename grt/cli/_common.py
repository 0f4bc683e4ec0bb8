"""One error path for GRT's command-line apps: a user's mistake is one line and exit code 2.

Every error in what the user gave subclasses :class:`grt.errors.UserError` and carries a message that
names the problem and the fix; :func:`exit_on_user_error` prints it without a traceback, and prints one
line with exit code 130 for Ctrl-C. Mistakes Hydra finds while it composes the config (an unknown key or
option, a value of the wrong type), before the app runs, are turned into the same one line by
:func:`run_cli`, which each Hydra app's ``cli()`` calls.

``CONF_DIR`` (:data:`grt.CONF_DIR`) is the config folder the Hydra apps give ``@hydra.main``: an absolute
path (the repository's ``conf/`` in a checkout, ``grt/conf`` in an installed wheel), because Hydra reads a
relative ``config_path`` as a Python package whenever the app's function lives in an imported module, which
it always does here (the ``python -m`` shims and console scripts import it). A user's own config folder
joins it with ``--config-dir DIR`` (Hydra's flag; docs/your-own-code.md): its groups' options show in
``--help`` beside GRT's (:func:`config_groups`).

Every ``--help`` starts with one line saying what the command does (:data:`ABOUT`, :func:`about_line`):
the Hydra apps' through ``conf/hydra/help/grt.yaml``, the others' through :class:`AppParser`.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import difflib
import os
import re
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path

from hydra.errors import (
    ConfigCompositionException,
    HydraException,
    OverrideParseException,
    SearchPathException,
)
from omegaconf import DictConfig
from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

from grt import CONF_DIR
from grt.cli.launchers import NO_SLURM, no_slurm  # registers slurm.yaml's resolvers too
from grt.config import BudgetSchema, add_resolver, budget_hint, unknown_budget_key
from grt.errors import INTERRUPTED, TERMINATED, OutputError, Terminated, UserError
from grt.fileio import write_bytes_atomic
from grt.runfolder.lock import discard_new
from grt.runfolder.record import resume_or
from grt.runfolder.resume import resume_overrides
from grt.targets import takes

_PACKAGE = Path(__file__).resolve().parents[1]  # grt/
_NOISE = ("full_key:", "object_type=", "reference_type=", "See https://hydra.cc", "Config search path:")


HIDDEN_GROUPS = ("paths",)  # config groups that are no user choice, left out of --help (with hydra/*)

#: What each command does: the first line of its ``--help`` (:func:`about_line`).
ABOUT = {
    "run": "red-team a policy: search small deformations of an object (CrashShapes) that make it fail",
    "evaluate": "score a policy on one object as it is (no deformation): its score and failure modes",
    "select": "choose the handles and anchors a red-team run moves and keeps on an object, and show them",
    "deform": "deform a mesh: move handle points, keep anchor points, write the smooth result",
    "blueteam": "fine-tune a red-teamed policy on its CrashShapes and measure what it gained (paper Table 3)",
    "train": "train a task's policy with PPO (rsl-rl)",
    "serve": "serve a GRT policy over grt-policy/1, for a run in another process or on another machine",
    "bench": "measure GRT's speed and accuracy against a baseline measured in the same run",
    "report": "the paper's tables (and report.html) of a run, a sweep or an experiments/ folder",
    "replay": "re-run one trial of a red-team run (a candidate's or the nominal object's), optionally filmed",
    "profile": "measure how much shape change breaks a policy: success against deformation size, random and "
               "adversarial, and two margins in mm",
    "objects": "list the built-in objects (size, faces, named regions), optionally export them",
    "setup": "install what an optional policy needs: ManiSkill's motion planners' numpy, Contact-GraspNet's weights",
    "calibrate": "check a ManiSkill task's nominal swap against the stock env, seed for seed (agreement, mass, "
                 "extents)",
}


def about_line(name: str) -> str:
    """The first line of ``grt-<name> --help``: the command and what it does."""
    return f"grt-{name} (python -m grt.{name}): {ABOUT[name]}"


def running_about() -> str:
    """:func:`about_line` of the running Hydra app (resolver ``grt_about``, ``conf/hydra/help/grt.yaml``)."""
    from hydra.core.hydra_config import HydraConfig

    name = HydraConfig.get().job.name if HydraConfig.initialized() else ""
    return about_line(name) if name in ABOUT else f"{name}: a GRT command"


class AppParser(argparse.ArgumentParser):
    """The argument parser of GRT's apps that do not use Hydra: ``--help`` starts with :func:`about_line`."""

    def __init__(self, name: str, **kwargs):
        super().__init__(prog=f"python -m grt.{name}", description=kwargs.pop("description", ABOUT[name]),
                         **kwargs)
        self.about = about_line(name)
        stop_on_sigterm()  # SIGTERM: one line and exit code 143, as for the Hydra apps

    def format_help(self) -> str:
        return f"{self.about}\n\n{super().format_help()}"


def group_options(group: str) -> list[str]:
    """The options of config group ``group`` in every config folder of the running app's search path: GRT's
    ``conf/`` and a user's ``--config-dir`` (YAML files; a schema registered in code is not an option)."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.object_type import ObjectType

    if not GlobalHydra.instance().is_initialized():
        return sorted(p.stem for p in (Path(CONF_DIR) / group).glob("*.yaml"))
    options: set[str] = set()
    for source in GlobalHydra.instance().config_loader().get_sources():
        if source.scheme() != "structured" and source.available() and source.is_group(group):
            options.update(source.list(group, ObjectType.CONFIG))
    options.update(_searchpath_options(group))
    return sorted(options)


def _searchpath_options(group: str) -> set[str]:
    """The options of ``group`` in the folders ``hydra.searchpath=[file://DIR]`` adds: Hydra records them in the
    running app's config sources, not in the loader's (a user's own tasks, listed by ``--help`` too)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return set()
    found: set[str] = set()
    for source in HydraConfig.get().runtime.config_sources or []:
        folder = Path(str(source.path)) / group if source.schema == "file" else None
        if folder is not None and folder.is_dir():
            found.update(p.stem for p in folder.glob("*.yaml"))
    return found


def config_groups() -> str:
    """The ``--help`` lines of the running app's config groups (resolver ``grt_config_groups``, used by
    ``conf/hydra/help/grt.yaml``): each group this command composes, its options (:func:`group_options`,
    a user's own among them) and the one chosen; ``paths`` and ``hydra/*`` are hidden."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return ""
    lines = []
    for group, chosen in sorted(HydraConfig.get().runtime.choices.items()):
        if group == "hydra" or group.startswith("hydra/") or group in HIDDEN_GROUPS:
            continue
        options = group_options(group)
        if options:
            lines.append(f"{group}: {', '.join(options)}  (now: {chosen if chosen is not None else 'none'})")
    return "\n".join(lines)


add_resolver("grt_config_groups", config_groups)
add_resolver("grt_about", running_about)
add_resolver("resume_or", resume_or)  # hydra.run.dir: a resumed run's own folder, else a new one


def find_user_error(exc: BaseException, also: tuple[type[BaseException], ...] = ()) -> BaseException | None:
    """The user error behind ``exc`` (Hydra wraps errors raised while instantiating), or ``None``.

    ``also``: more types to count as user errors (for an error class that does not subclass
    :class:`grt.errors.UserError`).
    """
    kinds = (UserError, *also)
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, kinds):
            return exc
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


@contextlib.contextmanager
def exit_on_user_error(*also: type[BaseException]):
    """Turn a user error (or one of the types ``also``) into ``error: <message>`` on stderr and exit code 2,
    Ctrl-C into one line and exit code 130, SIGTERM (:class:`grt.errors.Terminated`) into one line and exit code
    143. Inside a Hydra app, a folder this command made and saved nothing in is removed, and the line says so
    (:func:`grt.runfolder.lock.discard_new`)."""
    try:
        yield
    except KeyboardInterrupt as exc:
        stop, code = (("terminated (SIGTERM)", TERMINATED) if isinstance(exc, Terminated)
                      else ("interrupted (Ctrl-C)", INTERRUPTED))
        print(stop, file=sys.stderr)
        raise SystemExit(code) from None
    except Exception as exc:
        found = (find_user_error(exc, also) or _compose_error(exc) or _launcher_error(exc) or _search_path_error(exc)
                 or yaml_error(exc))
        if found is None:
            raise
        removed = _discard_run_folder()
        print(f"error: {found}" + (f" ({removed})" if removed else ""), file=sys.stderr)
        raise SystemExit(2) from None


def _discard_run_folder() -> str:
    """:func:`grt.runfolder.lock.discard_new` of the running Hydra app's folder (``""`` outside one)."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    try:
        if not HydraConfig.initialized() or HydraConfig.get().mode != RunMode.RUN:
            return ""
        return discard_new(Path(HydraConfig.get().runtime.output_dir))
    except Exception:  # noqa: BLE001 - no folder of this run (yet): nothing to remove
        return ""


def stop_on_sigterm() -> None:
    """Make SIGTERM (schedulers, ``timeout``) stop this process as Ctrl-C does: :class:`grt.errors.Terminated`
    is raised in the main thread, so the app says how to go on and exits with code 143. A second SIGTERM
    ends the process at once."""
    if threading.current_thread() is not threading.main_thread():
        return

    def terminated(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        raise Terminated

    signal.signal(signal.SIGTERM, terminated)


def run_cli(main: Callable[[], object]) -> None:
    """Call a ``@hydra.main`` app so that every user mistake is one ``error:`` line and exit code 2.

    Covers what happens before the app's own code runs: Hydra's composition errors (unknown key or
    option, wrong type, bad override syntax) and an output folder it cannot create or write. Other
    errors keep their traceback (exit code 1). ``HYDRA_FULL_ERROR=1`` set by the user is honoured.
    Use: ``def cli(): run_cli(main)``. SIGTERM stops the app as Ctrl-C does (:func:`stop_on_sigterm`).
    """
    stop_on_sigterm()
    previous = os.environ.get("HYDRA_FULL_ERROR")
    if previous == "1":
        with exit_on_user_error():
            main()
        return
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra re-raises what it would print (several lines, exit code 1)
    try:
        with exit_on_user_error():
            try:
                main()
            except OSError as exc:
                found = _setup_error(exc)
                if found is None:
                    raise
                raise found from exc
    finally:
        if previous is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = previous


def write_output(path: str | Path, data: bytes | str, flag: str = "--out PATH") -> None:
    """Write ``path`` whole or not at all (a temporary file renamed over it; Ctrl-C leaves no half file).

    Raises:
        OutputError: the folder is read-only or full (names the path and the fix).
    """
    try:
        write_bytes_atomic(path, data.encode() if isinstance(data, str) else data)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror}; choose a folder you can write to ({flag})") \
            from None


def one_line(text: str) -> str:
    """Hydra's and OmegaConf's several-line messages as one line (lists joined, object dumps dropped)."""
    parts: list[str] = []
    for raw in str(text).split("Config search path:")[0].splitlines():
        line = raw.strip()
        if not line or line.startswith(_NOISE):
            continue
        if raw.startswith("\t") and parts:  # an item of a list ("Available options in 'selector':")
            parts[-1] += (" " if parts[-1].endswith(":") else ", ") + line
        else:
            parts.append(line.rstrip("."))
    return "; ".join(parts)


def _compose_error(exc: BaseException) -> str | None:
    """One line for a mistake Hydra finds while composing a config, or ``None`` for other errors."""
    if not isinstance(exc, (ConfigCompositionException, OverrideParseException)):
        return None
    cause = exc.__cause__
    key = str(getattr(cause, "full_key", "") or "")
    in_budget = getattr(cause, "object_type", None) is BudgetSchema
    if isinstance(cause, (ConfigKeyError, ConfigAttributeError)) and in_budget:  # Hydra would hint at '+'
        return unknown_budget_key(key.split(".", 1)[1])
    if isinstance(cause, (ConfigKeyError, ConfigAttributeError)) and key.startswith("hydra.launcher."):
        return unknown_launcher_key(key, getattr(cause, "object_type", None))  # '+' would fail at launch
    if isinstance(cause, (ConfigKeyError, ConfigAttributeError)) and isinstance(exc, ConfigCompositionException):
        found = unknown_key(key, getattr(cause, "parent_node", None))
        if found is not None:
            return found
    text = one_line(str(exc))
    if text.startswith("Multiple values for ") and "override" in text:  # +GROUP=OPTION of a chosen group
        group = text.removeprefix("Multiple values for ").split(".")[0]
        return f"{group} is a config group this command already chooses: give {group}=OPTION (without '+')"
    if isinstance(exc, OverrideParseException):
        return quoting_hint(exc.override, text)
    if isinstance(cause, OmegaConfBaseException):
        text += "; " + one_line(str(cause))
    merge = re.match(r"Error merging override ([^=\s]+)=(.*); Cannot merge (DictConfig with ListConfig|ListConfig "
                     r"with DictConfig)", text)
    if merge:  # a mapping given where the YAML holds a list (failure_flags), or the reverse
        key, value = merge.group(1), merge.group(2)
        kind = "a list" if merge.group(3).startswith("DictConfig") else "a mapping"
        return (f"{key} is {kind} in the config, and Hydra merges only the same kind into it; to give "
                f"{value} instead, replace it: '~{key}' '+{key}={value}'")
    hint = budget_hint(key)
    return f"{text}; {hint}" if hint else text


def unknown_key(full_key: str, parent) -> str | None:
    """One line for ``a.b.KEY=V`` where the section ``a.b`` has no ``KEY`` (``optimizer.name=CMAA`` with
    ``optimizer=nevergrad``, ``calibrate.trials=0``): the close names and the section's settings, instead of
    Hydra's hint to add it with '+' (which would be refused as a key nothing reads). ``None`` where the
    section is empty (a mapping meant for new keys, such as ``task.session.env_kwargs``): Hydra's hint fits."""
    keys = [str(k) for k in parent if not str(k).startswith("_") and str(k) != "hydra"] \
        if isinstance(parent, DictConfig) else []
    if not full_key or not keys:
        return None
    section, _, name = full_key.rpartition(".")
    target = parent.get("_target_") if isinstance(parent, DictConfig) else None
    if target is not None and takes(str(target), name):  # an argument of the class its YAML leaves out
        return (f"{full_key} is an argument of {target} that the config does not set; add it with '+': "
                f"+{full_key}=VALUE")
    close = difflib.get_close_matches(name, keys, n=3, cutoff=0.6)
    text = f"{full_key} is not a setting of {section or 'the command'} (its keys are {', '.join(sorted(keys))})"
    if close:
        text += f"; did you mean {' or '.join(f'{section}.{c}' if section else c for c in close)}?"
    return text


def unknown_launcher_key(key: str, schema) -> str:
    """One line for a setting the chosen Hydra launcher does not have (``hydra.launcher.partion=cpu``)."""
    names = sorted(f.name for f in dataclasses.fields(schema) if not f.name.startswith("_")) \
        if dataclasses.is_dataclass(schema) else []
    text = f"{key}: the launcher has no such setting"
    if names:
        text += f" (its settings: {', '.join(names)})"
    if "additional_parameters" in names:
        text += f"; any other sbatch option: +hydra.launcher.additional_parameters.{key.rsplit('.', 1)[1]}=VALUE"
    return text


def quoting_hint(override: str, parser_message: str) -> str:
    """One line for an override Hydra's grammar cannot parse: most often a value (a file path) with a
    space, a non-ASCII letter or one of ``()[]{},'"``, which it reads only when quoted."""
    key, sep, value = override.partition("=")
    if not sep or not value or value[0] in "'\"[{":  # already quoted, a list or a dict: its own syntax error
        return f"cannot parse the override {override!r}: {parser_message}"
    if "'" not in value:  # Hydra's single quotes inside the shell's double quotes
        shell = f'"{key}=\'{value}\'"' if not any(c in value for c in '"$`\\') else \
            "'" + f"{key}=\"{value}\"" + "'"
    else:  # Hydra's double quotes inside the shell's single quotes ('\'' is the shell's quote)
        shell = "'" + f'{key}="{value}"'.replace("'", "'\\''") + "'"
    return (f"cannot parse the override {override!r} ({parser_message.split(';')[0]}): a value with spaces, "
            f"non-ASCII letters or any of ()[]{{}},'\" must be quoted for Hydra, inside the shell's quotes: "
            f"{shell}")


def _launcher_error(exc: BaseException) -> UserError | None:
    """One line for submitit's own refusal of a SLURM launcher where SLURM is missing (``grt.run`` refuses one
    given on its command line before Hydra starts: :func:`grt.cli.launchers.check_launcher`)."""
    for _ in range(10):
        if exc is None:
            return None
        if isinstance(exc, RuntimeError) and str(exc).startswith(NO_SLURM):
            return no_slurm("submitit_slurm")
        exc = exc.__cause__ or exc.__context__
    return None


def yaml_error(exc: BaseException) -> str | None:
    """One line for a config file YAML cannot read (a syntax error, a TAB indent), found anywhere in the chain
    of ``exc``: the file, line and column and what YAML expected; ``None`` for other errors."""
    import yaml

    for _ in range(10):
        if exc is None or isinstance(exc, yaml.YAMLError):
            break
        exc = exc.__cause__ or exc.__context__
    if not isinstance(exc, yaml.MarkedYAMLError) or exc.problem_mark is None:
        return None
    mark = exc.problem_mark
    where = f"{mark.name}, line {mark.line + 1}, column {mark.column + 1}"
    what = ", ".join(filter(None, [exc.problem, exc.context])).replace("character '\\t'", "a TAB character")
    fix = ("YAML indents with spaces only: replace the TAB with spaces" if "'\\t'" in exc.problem else
           "fix the YAML there (a bracket or quote left open, a colon where a value should be, an indent)")
    return f"{where}: YAML cannot read the config file ({what}); {fix}"


def _search_path_error(exc: BaseException) -> str | None:
    """One line for a ``--config-dir DIR`` that is no folder (Hydra's ``SearchPathException``)."""
    if not isinstance(exc, SearchPathException):
        return None
    return (f"--config-dir: {str(exc).replace('Additional config directory', 'the config folder')}; give the "
            "folder that holds your config groups (policy/, task/, experiment/ ...)")


def _setup_error(exc: OSError) -> OutputError | None:
    """An output folder Hydra could not create or write before the app ran (no GRT code below Hydra's).

    The frames above Hydra's (this module, the app's ``cli()``) only launch it; a GRT frame below a Hydra
    frame is the app's own code running, whose error handling applies.
    """
    if isinstance(exc, HydraException) or not exc.filename:
        return None
    tb, in_hydra = exc.__traceback__, False
    while tb is not None:
        path = Path(tb.tb_frame.f_code.co_filename).resolve()
        if _PACKAGE not in path.parents:
            in_hydra = True
        elif in_hydra:
            return None  # raised by the app: its own error handling applies
        tb = tb.tb_next
    return OutputError(f"cannot write {exc.filename}: {exc.strerror}; give an output folder you can write "
                       "to: hydra.run.dir=PATH (hydra.sweep.dir=PATH with -m)")


def recorded_config_dir(overrides: list[str]) -> str | None:
    """The ``--config-dir`` the folder of ``resume=DIR`` was made with (Hydra's record of its config sources,
    ``DIR/.hydra/hydra.yaml``), when that folder still exists; ``None`` otherwise."""
    from omegaconf import OmegaConf

    resume = next((line.partition("=")[2] for line in reversed(overrides) if line.startswith("resume=")), "")
    record = Path(resume) / ".hydra" / "hydra.yaml" if resume else None
    if record is None or not record.is_file():
        return None
    try:
        sources = OmegaConf.select(OmegaConf.load(record), "hydra.runtime.config_sources") or []
    except Exception:  # noqa: BLE001 - an unreadable record: the resume's own checks say so
        return None
    for source in sources:
        if source.get("provider") == "command-line" and source.get("schema") == "file" and Path(source.path).is_dir():
            return str(source.path)
    return None


def recorded_searchpath(overrides: list[str]) -> list[str]:
    """``[hydra.searchpath=[...]]``, the config folders the folder of ``resume=DIR`` was made with (Hydra's record,
    ``DIR/.hydra/hydra.yaml``), when ``overrides`` give none: a run of a task from the user's own folder
    resumes from its folder alone; ``[]`` otherwise."""
    from omegaconf import OmegaConf

    resume = next((line.partition("=")[2] for line in reversed(overrides) if line.startswith("resume=")), "")
    record = Path(resume) / ".hydra" / "hydra.yaml" if resume else None
    if record is None or not record.is_file() or any(o.startswith("hydra.searchpath=") for o in overrides):
        return []
    try:
        given = OmegaConf.select(OmegaConf.load(record), "hydra.overrides.hydra") or []
    except Exception:  # noqa: BLE001 - an unreadable record: the resume's own checks say so
        return []
    return [str(o) for o in given if str(o).startswith("hydra.searchpath=")][-1:]


#: The flags of a Hydra app's command line (``@hydra.main``'s), by the name argparse gives each: ``None`` for a
#: switch, else the values it takes (``()``: any; ``info`` alone may also be given without one).
HYDRA_FLAGS: dict[str, tuple[str, ...] | None] = {
    "help": None, "hydra_help": None, "version": None, "resolve": None, "run": None, "multirun": None,
    "shell_completion": None, "cfg": ("job", "hydra", "all"), "package": (), "config_path": (), "config_name": (),
    "config_dir": (), "experimental_rerun": (),
    "info": ("all", "config", "defaults", "defaults-tree", "plugins", "searchpath")}
_SHORT = {"help": "-h", "cfg": "-c", "package": "-p", "run": "-r", "multirun": "-m", "shell_completion": "-sc",
          "config_path": "-cp", "config_name": "-cn", "config_dir": "-cd", "info": "-i"}


def parse_command(argv: list[str] | None = None) -> argparse.Namespace:
    """A Hydra app's command line (``sys.argv[1:]`` by default): its ``overrides`` and flags, read as
    ``@hydra.main`` reads them, so that GRT can check and rewrite the overrides before Hydra starts
    (:func:`launch` hands the command on)."""
    parser = argparse.ArgumentParser(add_help=False, prog=Path(sys.argv[0]).name)
    parser.add_argument("overrides", nargs="*")
    for name, values in HYDRA_FLAGS.items():
        flags = [f"--{name.replace('_', '-')}", *([_SHORT[name]] if name in _SHORT else [])]
        if values is None:
            parser.add_argument(*flags, dest=name, action="store_true")
        elif name == "info":
            parser.add_argument(*flags, dest=name, nargs="?", const="all", choices=values)
        else:
            parser.add_argument(*flags, dest=name, choices=values or None)
    return parser.parse_args(sys.argv[1:] if argv is None else list(argv))


def launch(app: Callable[[], object], args: argparse.Namespace) -> None:
    """Run the ``@hydra.main`` ``app`` on the command line ``args`` (:func:`parse_command`'s, its overrides
    perhaps rewritten: a resume's) through Hydra's public entry point: ``app()`` reads the process's
    arguments, which are the command ``args`` gives while it runs and are restored after it."""
    command = []
    for name, values in HYDRA_FLAGS.items():
        value, flag = getattr(args, name), "--" + name.replace("_", "-")
        if values is None and value:
            command.append(flag)
        elif values is not None and value is not None:
            command.append(f"{flag}={value}")
    given = sys.argv
    sys.argv = [given[0], *command, *args.overrides]
    try:
        app()
    finally:
        sys.argv = given


def resumable_cli(main: Callable, kind, argv: list[str] | None = None) -> None:
    """Run the Hydra app ``main`` from the command line, a ``resume=DIR`` first checked and made the folder's
    own command for its ``kind`` (:data:`grt.runfolder.resume.TRAINING`, ``STUDY``) before Hydra starts, as
    ``grt-run`` does (:func:`grt.cli.run.cli`)."""
    args = parse_command(argv)
    with exit_on_user_error():
        if any("resume=" in arg for arg in args.overrides):
            args.overrides = resume_overrides(args.overrides, kind)
            args.config_dir = args.config_dir or recorded_config_dir(args.overrides)  # the user's config folder
            args.overrides = [*recorded_searchpath(args.overrides), *args.overrides]  # ... or hydra.searchpath
    run_cli(lambda: launch(main, args))
