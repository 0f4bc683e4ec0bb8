"""GRT tasks: one ManiSkill env + one :class:`~grt.tasks.base.TaskSession` per task.

A task is found through its config alone: ``conf/task/<name>.yaml`` names its session class in
``session._target_`` (what Hydra instantiates in every evaluator worker), and :func:`session_class`
reads it there. :data:`TASKS` (task name -> session class path) is derived from those files, so adding a
task = one module (env + session) + one YAML; the tests iterate over ``TASKS``. Class paths are kept as
strings so that importing ``grt.tasks`` does not start the simulator.
"""

from __future__ import annotations

from pathlib import Path

from hydra.utils import get_class
from omegaconf import OmegaConf

from grt.objects import list_objects
from grt.tasks.base import COMMON_MODES, EpisodeSession, TaskInputError, TaskSession, TrialOutcome

TASK_CONF = Path(__file__).resolve().parents[2] / "conf" / "task"


def _session_target(path: Path) -> str | None:
    """``session._target_`` of a task YAML, or of the task it extends (``defaults: [grasp, _self_]``)."""
    cfg = OmegaConf.load(path)
    target = OmegaConf.select(cfg, "session._target_")
    if target is not None:
        return str(target)
    for base in cfg.get("defaults") or []:
        if isinstance(base, str) and base != "_self_" and (path.parent / f"{base}.yaml").is_file():
            found = _session_target(path.parent / f"{base}.yaml")
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
    return get_class(task["session"]["_target_"])


def get_task(name: str) -> type[TaskSession]:
    """The session class of task ``name`` (``conf/task/<name>.yaml``).

    Raises:
        KeyError: the task is unknown (the message lists the known ones).
    """
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; known tasks: {sorted(TASKS)}")
    return get_class(TASKS[name])


def preflight(task: dict, policy, mesh, object_scale: float = 1.0) -> None:
    """Refuse, before any simulation, an object the task cannot use or a policy made for another task.

    Args:
        task: the task config as a plain dict (``name``, ``session``).
        policy: the instantiated policy; checked when it has ``check(task, obs_spec, num_actions)``.
        mesh: the nominal object (meters).
        object_scale: the scale ``mesh`` was loaded with (the app's ``object_scale``).

    Raises:
        grt.policies.rsl_rl.CheckpointError: a policy for another task/observation, naming both sides.
        grt.tasks.socket.PlugFitError (or the task's own error): an object the task cannot use.
        TaskInputError: ``object_scale`` set while the task's session reloads a mesh file by itself.
    """
    for key in ("socket_object", "handle_object"):  # sessions that rebuild a part from the nominal mesh file
        value = task["session"].get(key)
        if object_scale != 1.0 and value is not None and str(value) not in list_objects():
            raise TaskInputError(f"object_scale={object_scale:g}: task.session.{key}={value} is loaded by the task "
                                 "without it; export the mesh in meters and leave object_scale=1.0")
    session = session_class(task)  # a variant YAML (grasp_2cam) names the same class
    session.check_object(mesh, **{k: v for k, v in task["session"].items() if k != "_target_"})
    check = getattr(policy, "check", None)
    if check is not None:
        spec = session.observation_spec(**{k: v for k, v in task["session"].items() if k == "cloud_points"})
        check(getattr(session, "task_name", "") or task["name"], spec, session.num_actions)


__all__ = ["COMMON_MODES", "TASKS", "EpisodeSession", "TaskSession", "TrialOutcome", "get_task", "preflight",
           "session_class"]
