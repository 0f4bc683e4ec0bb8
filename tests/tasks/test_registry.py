"""The task registry is read from conf/task: one place for the lookup, the modes and the action size."""

from __future__ import annotations

from grt.tasks import COMMON_MODES, TASKS, get_task, session_class


def test_every_task_config_names_its_session_and_variants_find_their_base():
    assert {"grasp", "grasp_2cam", "insertion", "drawer"} <= set(TASKS)
    assert TASKS["grasp_2cam"] == TASKS["grasp"]  # the variant YAML names no class of its own
    assert session_class({"session": {"_target_": TASKS["insertion"]}}) is get_task("insertion")


def test_each_task_declares_its_own_failure_modes_and_action_size():
    modes = {name: get_task(name).failure_modes for name in TASKS}
    assert all(set(COMMON_MODES) <= set(m) and len(set(m)) == len(m) for m in modes.values())
    assert "jammed" in modes["insertion"] and "jammed" not in modes["drawer"] and "jammed" not in modes["grasp"]
    assert get_task("insertion").num_actions == 6 and get_task("drawer").num_actions == 9


def test_every_mode_of_every_task_is_explained_in_its_module_docstring():
    """report.html explains each mode it shows from the task module's docstring (issue 40): one text, checked
    here against the modes each session declares."""
    from grt.tasks.base import mode_meanings

    for name, target in TASKS.items():
        meanings = mode_meanings(target)
        missing = [m for m in get_task(name).failure_modes if not meanings.get(m)]
        assert not missing, (name, missing)
    assert "IK" in mode_meanings(TASKS["grasp"])["unreachable"]
