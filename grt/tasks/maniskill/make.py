"""``gym.make`` of a ManiSkill env with a task's settings, a mistake in them named in one line.

ManiSkill refuses a mistyped observation mode, control mode or robot with an ``AssertionError`` or a
``RuntimeError`` deep in its env's constructor (a 70-80 line traceback after the env began to build):
:func:`make_env` checks the observation mode and the robots first, and turns the control mode's refusal
into one line naming the modes the robot has and the close one.
"""

from __future__ import annotations

import difflib
import re

from grt.tasks.base import TaskInputError


class EnvBuildError(TaskInputError):
    """The registered env does not build with the task's settings (``gym.make`` refused or raised)."""


VISUAL = ("rgb", "depth", "segmentation", "position", "normal", "albedo")
MODES = ("state", "state_dict", "none", "sensor_data", "rgb", "depth", "segmentation", "rgbd", "pointcloud")


def make_env(env_id: str, kwargs: dict):
    """``gymnasium.make(env_id, **kwargs)``, after checking ``obs_mode`` and ``robot_uids``.

    Raises:
        EnvBuildError: an observation mode, control mode or robot ManiSkill does not know (one line with the
            setting, what it accepts and the close name), or anything else the env raised while it was built
            (its type and first line).
    """
    import gymnasium as gym

    check_obs_mode(kwargs.get("obs_mode"))
    check_robots(kwargs.get("robot_uids"))
    try:
        return gym.make(env_id, **kwargs)
    except TaskInputError:
        raise  # GRT's own refusal from inside the env's build (the swap's actor check)
    except Exception as err:  # noqa: BLE001 - whatever the env's own set-up raises: its settings are the user's
        found = re.match(r"(\S+) not in supported modes: \[(.*)\]", str(err)) if isinstance(err, AssertionError) else None
        if found is None:
            raise EnvBuildError(f"{env_id} fails to build with the task's settings ({type(err).__name__}: "
                                f"{str(err).splitlines()[0] if str(err) else ''}); check task.session.env_kwargs, "
                                "obs_mode and control_mode against the env") from None
        modes = [m.strip(" '\"") for m in found.group(2).split(",")]
        raise EnvBuildError(f"task.session.control_mode={found.group(1)} is not a control mode of {env_id}'s robot"
                            f"{_close(found.group(1), modes)}; its modes: {', '.join(modes)}") from None


def check_obs_mode(obs_mode) -> None:
    """Refuse an observation mode ManiSkill would refuse (``statee``), naming the close one and the modes."""
    if obs_mode is None:
        return
    parts = str(obs_mode).replace("pointcloud", "position+rgb+segmentation").split("+")
    if all(p in (*VISUAL, "state", "state_dict", "none") for p in parts) or str(obs_mode) in MODES:
        return
    raise EnvBuildError(f"task.session.obs_mode={obs_mode} is not a ManiSkill observation mode"
                        f"{_close(str(obs_mode), MODES)}; give one of {', '.join(MODES)} (or textures joined "
                        f"with +: {'+'.join(VISUAL[:2])})")


def check_robots(robot_uids) -> None:
    """Refuse a robot ManiSkill has not registered (``robot_uids=panda_typo``), naming the close ones."""
    if robot_uids is None:
        return
    from mani_skill.agents.registration import REGISTERED_AGENTS

    given = [robot_uids] if isinstance(robot_uids, str) else list(robot_uids)
    for uid in given:
        if str(uid) not in REGISTERED_AGENTS:
            raise EnvBuildError(f"task.session.env_kwargs.robot_uids={uid} is not a registered ManiSkill robot"
                                 f"{_close(str(uid), list(REGISTERED_AGENTS))}; {len(REGISTERED_AGENTS)} are "
                                 "registered (mani_skill.agents.registration.REGISTERED_AGENTS)")


def _close(given: str, names) -> str:
    close = difflib.get_close_matches(given, list(names), n=3, cutoff=0.6)
    return f" (did you mean {' or '.join(close)}?)" if close else ""
