"""GRT tasks: one ManiSkill env + one :class:`~grt.tasks.base.TaskSession` per task.

``TASKS`` maps a task name (= its ``conf/task/<name>.yaml``) to its session class path; it is kept as
strings so that importing ``grt.tasks`` does not start the simulator. Adding a task = one module
(env + session) + one YAML + one line here; the tests iterate over ``TASKS``.
"""

from __future__ import annotations

import importlib

from grt.tasks.base import FAILURE_MODES, EpisodeSession, TaskSession, TrialOutcome

TASKS: dict[str, str] = {
    "grasp": "grt.tasks.grasp.GraspSession",
    "insertion": "grt.tasks.insertion.InsertionSession",
    "drawer": "grt.tasks.drawer.DrawerSession",
}


def get_task(name: str) -> type[TaskSession]:
    """The session class of task ``name``.

    Raises:
        KeyError: the task is unknown (the message lists the known ones).
    """
    if name not in TASKS:
        raise KeyError(f"unknown task {name!r}; known tasks: {sorted(TASKS)}")
    module, _, cls = TASKS[name].rpartition(".")
    return getattr(importlib.import_module(module), cls)


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
    from hydra.utils import get_class

    from grt.objects import list_objects
    from grt.tasks.base import TaskInputError

    for key in ("socket_object", "handle_object"):  # sessions that rebuild a part from the nominal mesh file
        value = task["session"].get(key)
        if object_scale != 1.0 and value is not None and str(value) not in list_objects():
            raise TaskInputError(f"object_scale={object_scale:g}: task.session.{key}={value} is loaded by the task "
                                 "without it; export the mesh in meters and leave object_scale=1.0")
    session = get_class(task["session"]["_target_"])  # a variant YAML (grasp_2cam) names the same class
    session.check_object(mesh, **{k: v for k, v in task["session"].items() if k != "_target_"})
    check = getattr(policy, "check", None)
    if check is not None:
        spec = session.observation_spec(**{k: v for k, v in task["session"].items() if k == "cloud_points"})
        check(getattr(session, "task_name", "") or task["name"], spec, session.num_actions)


__all__ = ["FAILURE_MODES", "TASKS", "EpisodeSession", "TaskSession", "TrialOutcome", "get_task", "preflight"]
