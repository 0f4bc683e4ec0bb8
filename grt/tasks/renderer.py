"""Whether SAPIEN finds a Vulkan device here: checked once, first, by a command whose task simulates in SAPIEN.

SAPIEN needs a Vulkan device even for state-only episodes (on a CPU machine, Mesa's lavapipe driver). Without
one, every simulator worker fails as it starts (``vk::createInstanceUnique: ErrorIncompatibleDriver``), after
the object was prepared: :func:`check_renderer` says so in one line, with the fix, before any of that.
"""

from __future__ import annotations

import functools

from grt.tasks.base import TaskInputError

FIX = ("SAPIEN (the simulator) needs Vulkan even without a camera: a GPU's driver, or on a CPU Mesa's lavapipe "
       ">= 24.3 (Debian/Ubuntu: apt-get install mesa-vulkan-drivers libvulkan1; Debian 12 from "
       "bookworm-backports; in a checkout, make setup installs it)")


class RendererError(TaskInputError):
    """No Vulkan device SAPIEN can use on this machine."""


@functools.lru_cache(maxsize=1)
def renderer_problem() -> str | None:
    """Why SAPIEN cannot render here (one line with the fix), or ``None`` when its renderer starts."""
    try:
        import sapien

        sapien.render.RenderSystem()  # raises where no Vulkan device (lavapipe on a CPU) is found
    except Exception as exc:  # noqa: BLE001 - any failure means no simulator here, said in one line
        first = (str(exc).splitlines() or [""])[0]
        return f"no Vulkan device on this machine ({type(exc).__name__}: {first}); {FIX}"
    return None


def check_renderer(task: dict) -> None:
    """Refuse a task whose sessions simulate in SAPIEN with a renderer (GRT's own tasks but with
    ``render_backend: none``) on a machine where SAPIEN finds no Vulkan device.

    Raises:
        RendererError: one line: what SAPIEN said and how to install a driver.
    """
    session = task.get("session") or {}
    if not str(session.get("_target_", "")).startswith("grt.tasks.") or session.get("render_backend") == "none":
        return
    problem = renderer_problem()
    if problem is not None:
        raise RendererError(problem)
