"""GRT tasks: one ManiSkill env + one :class:`~grt.tasks.base.TaskSession` per task.

``TASKS`` maps a task name (= its ``conf/task/<name>.yaml``) to its session class path; it is kept as
strings so that importing ``grt.tasks`` does not start the simulator. Adding a task = one module
(env + session) + one YAML + one line here; the tests iterate over ``TASKS``.
"""

from __future__ import annotations

import importlib

from grt.tasks.base import FAILURE_MODES, TaskSession, TrialOutcome

TASKS: dict[str, str] = {
    "grasp": "grt.tasks.grasp.GraspSession",
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


__all__ = ["FAILURE_MODES", "TASKS", "TaskSession", "TrialOutcome", "get_task"]
