"""GRT tasks: one ManiSkill env + one :class:`~grt.tasks.base.TaskSession` per task.

A task is found through its config alone: ``conf/task/<name>.yaml`` names its session class in
``session._target_`` (what Hydra instantiates in every evaluator worker), and :func:`session_class`
reads it there. :data:`TASKS` (task name -> session class path) is derived from those files, so adding a
task = one module (env + session) + one YAML; the tests iterate over ``TASKS``. Class paths are kept as
strings so that importing ``grt.tasks`` does not start the simulator.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from grt import CONF_DIR
from grt.config.records import chosen, read_yaml
from grt.objects import list_objects
from grt.policies.base import POLICY_KINDS, policy_kind
from grt.targets import build, locate
from grt.tasks.base import COMMON_MODES, TaskInputError, TaskSession, TrialOutcome
from grt.tasks.batched import EpisodeSession

TASK_CONF = Path(CONF_DIR) / "task"  # the shipped tasks, in a checkout or an installed wheel
POLICY_CONF = TASK_CONF.parent / "policy"


def _session_target(path: Path, key: str = "session._target_") -> str | None:
    """``session._target_`` (or ``key``) of a task YAML, or of the one it extends (``defaults: [grasp, _self_]``)."""
    cfg = read_yaml(path) or {}
    target = cfg
    for part in key.split("."):
        target = target.get(part) if isinstance(target, Mapping) else None
    if target is not None:
        return str(target)
    for base in cfg.get("defaults") or []:
        if isinstance(base, str) and base != "_self_" and (path.parent / f"{base}.yaml").is_file():
            found = _session_target(path.parent / f"{base}.yaml", key)
            if found is not None:
                return found
    return None


def _find_tasks(folder: Path = TASK_CONF) -> dict[str, str]:
    found = {p.stem: _session_target(p) for p in sorted(folder.glob("*.yaml"))}
    return {name: target for name, target in found.items() if target is not None}


#: task name (= ``conf/task/<name>.yaml``) -> its session class path, read from the task configs.
TASKS: dict[str, str] = _find_tasks()


def session_class(task: dict) -> type[TaskSession]:
    """The session class of a task config (a plain dict with ``session._target_``), not instantiated."""
    return locate(str(task["session"]["_target_"]), "task.session")


def get_task(name: str) -> type[TaskSession]:
    """The session class of task ``name`` (``conf/task/<name>.yaml``).

    Raises:
        KeyError: the task is unknown (the message lists the known ones).
    """
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; known tasks: {sorted(TASKS)}")
    return locate(TASKS[name], "task.session")


class PolicyKindError(TaskInputError):
    """A policy of a kind the task cannot run (a grasp planner on a closed-loop task, or the reverse)."""


def check_policy_kind(task: dict, policy_class: type, name: str | None = None) -> None:
    """Refuse a policy whose kind (:func:`grt.policies.base.policy_kind`) the task's session cannot run.

    Args:
        task: the task config as a plain dict (``name``, ``session``).
        policy_class: the policy's class (not instantiated: a network's weights need not be loaded).
        name: the policy's config name (``policy=NAME``), for the message; ``None``: the class alone.

    Raises:
        PolicyKindError: names the task and the kinds it runs, the policy and its kind, and the shipped
            policies that fit the task.
    """
    needs = session_class(task).policy_kinds
    kind = policy_kind(policy_class)
    if not needs or kind in needs:
        return
    task_name = task.get("name", "?")
    what = POLICY_KINDS.get(kind, "none of the kinds a task runs (no plan or act method)")
    policy = f"policy={name} ({policy_class.__name__})" if name else f"the policy {policy_class.__name__}"
    fits = fitting_policies(task_name, needs)
    hint = f"; policies that fit: {', '.join(f'policy={p}' for p in fits)}" if fits else ""
    raise PolicyKindError(f"{policy} is {what}, but task={task_name} runs "
                          f"{' or '.join(POLICY_KINDS[k] for k in needs)}{hint}")


def fitting_policies(task_name: str, kinds: tuple[str, ...], folder: Path = POLICY_CONF) -> list[str]:
    """The shipped policy configs of the given kinds that are not made for another task (by their ``task``
    key or their name's ``<task>_`` prefix); only called to word a refusal (it imports the classes)."""
    others = [t for t in TASKS if t != task_name]
    found = []
    for path in sorted(folder.glob("*.yaml")):
        declared = _session_target(path, "task")
        if (declared is not None and declared != task_name) or any(path.stem.startswith(f"{t}_") for t in others):
            continue
        try:
            target = _session_target(path, "_target_")
            obj = locate(target, "policy") if target is not None else None
            if isinstance(obj, type) and policy_kind(obj) in kinds:  # a factory (remote) has no fixed kind
                found.append(path.stem)
        except Exception:  # noqa: BLE001, S112 - a config whose class does not import is simply not listed
            continue
    return found


def _policy_class(policy) -> tuple[type | None, object]:
    """``(class, instance)`` of a policy given as an instance or as a config with ``_target_`` (not built)."""
    if isinstance(policy, Mapping) and "_target_" in policy:
        target = locate(str(policy["_target_"]), "policy")  # a class Python cannot find: one line
        if isinstance(target, type):
            return target, None
        built = build(policy, "policy")  # a factory (policy=remote's connect): its product has the class
        return type(built), built
    return (type(policy), policy) if policy is not None else (None, None)


def check_fit(task: dict, policy=None) -> None:
    """What needs no object, checked first (before the object is prepared, which takes seconds to minutes): that
    the machine has the Vulkan device the task's simulator needs (:func:`grt.tasks.renderer.check_renderer`) and
    that the policy's kind fits the task (its class only, nothing built; :func:`preflight` checks the rest), and
    what the policy class checks of its own config without being built (a ``check_config(cfg)`` classmethod:
    ``policy=motion_planner``'s control mode and env).

    Raises:
        RendererError: no Vulkan device. PolicyKindError: a policy of a kind the task cannot run.
    """
    from grt.tasks.renderer import check_renderer

    check_renderer(task)
    if isinstance(policy, Mapping) and "_target_" in policy:
        target = locate(str(policy["_target_"]), "policy")  # a class Python cannot find: one line
        if isinstance(target, type):
            check_policy_kind(task, target, chosen("policy"))
            check = getattr(target, "check_config", None)  # a class's own checks of its config, nothing built
            if callable(check):
                check(policy)


def preflight(task: dict, policy, mesh, object_scale: float = 1.0) -> None:
    """Refuse, before any simulation, an object the task cannot use or a policy made for another task.

    Args:
        task: the task config as a plain dict (``name``, ``session``).
        policy: the policy, or its config as a plain dict with ``_target_`` (its class is checked first,
            then it is built); checked when it has ``check(task, obs_spec, num_actions)``.
        mesh: the nominal object (meters).
        object_scale: the scale ``mesh`` was loaded with (the app's ``object_scale``).

    Raises:
        PolicyKindError: a policy of a kind the task cannot run (a grasp planner on insertion, ...).
        grt.policies.rsl_rl.CheckpointError: a policy for another task/observation, naming both sides.
        grt.tasks.socket.PlugFitError (or the task's own error): an object the task cannot use.
        TaskInputError: ``object_scale`` set while the task's session reloads a mesh file by itself.
    """
    cls, built = _policy_class(policy)
    if cls is not None:
        check_policy_kind(task, cls, chosen("policy"))
    for key in ("socket_object", "handle_object"):  # sessions that rebuild a part from the nominal mesh file
        value = task["session"].get(key)
        if object_scale != 1.0 and value is not None and str(value) not in list_objects():
            raise TaskInputError(f"object_scale={object_scale:g}: task.session.{key}={value} is loaded by the task "
                                 "without it; export the mesh in meters and leave object_scale=1.0")
    session = session_class(task)  # a variant YAML (grasp_2cam) names the same class
    session.check_object(mesh, **{k: v for k, v in task["session"].items() if k != "_target_"})
    if built is None and cls is not None:
        built = build(policy, "policy")  # a constructor that raises: one line, its traceback in a file
    check = getattr(built, "check", None)
    probe = getattr(session, "probe_policies", False) and built is not None and policy_kind(type(built)) == "closed_loop"
    if check is None and not probe:
        return
    kwargs = {k: v for k, v in task["session"].items() if k != "_target_"}
    spec = session.observation_spec(**kwargs)
    num_actions = session.action_size(**kwargs) if hasattr(session, "action_size") else session.num_actions
    name = getattr(session, "task_name", "") or task["name"]
    if check is not None:
        check(name, spec, num_actions)
    else:
        check_policy_io(built, name, spec, num_actions)


class PolicySizeError(TaskInputError):
    """A policy whose observation or action size does not fit the task's env."""


def check_policy_io(policy, task_name: str, spec: dict, num_actions: int) -> None:
    """Refuse a closed-loop policy (with no ``check`` of its own) whose sizes do not fit the task's: the
    sizes it declares (``obs_spec``, ``num_actions`` attributes) or, when it declares none, what it does
    with one zero observation of the task's sizes (its actions must be ``(1, num_actions)``).

    Raises:
        PolicySizeError: one line naming the policy's sizes and the task's.
    """
    what = type(policy).__name__
    shapes = ", ".join(f"{k} {tuple(v)}" for k, v in spec.items())
    gives = f"task={task_name} gives observations {shapes} and takes {num_actions} actions"
    declared = getattr(policy, "obs_spec", None)
    if isinstance(declared, Mapping):
        for group, want in declared.items():
            have = tuple(spec[group]) if group in spec else None
            if have != tuple(want):
                raise PolicySizeError(f"{what} reads observation {group!r} of shape {tuple(want)}, but {gives}")
    wants = getattr(policy, "num_actions", None)
    if isinstance(wants, int) and wants != num_actions:
        raise PolicySizeError(f"{what} writes {wants} actions, but {gives}")
    if isinstance(declared, Mapping) and isinstance(wants, int):
        return
    import numpy as np

    zeros = {k: np.zeros((1, *v), np.float32) for k, v in spec.items()}
    try:
        action = np.asarray(policy.act(zeros))
    except Exception as err:  # noqa: BLE001 - whatever a wrong size raises inside a user's code
        raise PolicySizeError(f"{what} fails on an observation of the task's sizes ({type(err).__name__}: "
                              f"{str(err).splitlines()[0] if str(err) else ''}): {gives}") from None
    if action.shape != (1, num_actions):
        raise PolicySizeError(f"{what} wrote actions of shape {action.shape} for one observation, but {gives} "
                              f"(actions of shape (1, {num_actions}))")


#: ``object: actor`` (a task YAML's default for ManiSkill tasks): the swapped actor's own geometry.
ACTOR_OBJECT = "actor"


def task_description(task) -> str:
    """What the task is, in words (``task.description``; the VLM selector reads it). A user's task YAML may
    leave it out: then a sentence made from the task's name and env (said so in the words themselves)."""
    if task.get("description"):
        return str(task.get("description"))
    env = task.get("env_id") or (task.get("session") or {}).get("env_id")
    return f"the {task.get('name', 'unnamed')} task" + (f" (ManiSkill env {env})" if env else "") + \
        " (no task.description given)"


def task_object(task, spec, cache_dir: str | Path) -> str:
    """The object spec to load (:func:`grt.geometry.mesh.load_mesh`): ``spec`` itself, or for ``actor`` the
    task's stock actor geometry (its session's ``nominal_object``, GRT's frame), written once as an OBJ
    under ``cache_dir/maniskill`` (named by the task and a hash of its session config) and its path.

    Raises:
        TaskInputError: ``object=actor`` for a task that has no actor of its own.
    """
    import hashlib
    import json

    if str(spec) != ACTOR_OBJECT:
        return str(spec)
    if not isinstance(task, Mapping) or "session" not in task:
        raise TaskInputError("object=actor is the swapped actor of a ManiSkill task, and this command has no task "
                             "config; give object=NAME (python -m grt.objects) or a mesh file (meters, GRT's frame)")
    if not isinstance(task, dict):  # an app's config node: its plain data
        from grt.config import plain

        task = plain(task)
    cls = session_class(task)
    make = getattr(cls, "nominal_object", None)
    if make is None:
        raise TaskInputError(f"object=actor: task={task.get('name', '?')} has no actor of its own to take the "
                             "object from; give object=NAME (python -m grt.objects) or a mesh file")
    kwargs = {k: v for k, v in task["session"].items() if k not in ("_target_", "task_name")}
    digest = hashlib.sha256(json.dumps(kwargs, sort_keys=True, default=str).encode()).hexdigest()[:10]
    path = Path(cache_dir).expanduser() / "maniskill" / f"{task.get('name', 'task')}-{digest}.obj"
    if not path.is_file():
        from grt.fileio import write_bytes_atomic

        path.parent.mkdir(parents=True, exist_ok=True)
        mesh = make(**{k: v for k, v in task["session"].items() if k != "_target_"})
        write_bytes_atomic(path, mesh.export(file_type="obj").encode())
    return str(path)


__all__ = ["ACTOR_OBJECT", "COMMON_MODES", "TASKS", "EpisodeSession", "PolicyKindError", "PolicySizeError",
           "TaskSession", "TrialOutcome", "check_policy_io", "check_policy_kind", "get_task", "preflight",
           "session_class", "task_object"]
