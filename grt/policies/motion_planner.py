"""ManiSkill's motion-planning solutions as a GRT policy: a policy that drives the env itself.

ManiSkill ships a scripted solution for many of its tabletop tasks
(``mani_skill/examples/motionplanning/panda/solutions/*.py``): ``solve(env, seed=...)`` resets the env with
the seed, reads the scene (the object's pose and oriented bounding box, the goal), plans grasp and transfer
motions with mplib (screw and RRT plans) and steps the env along them in ``pd_joint_pos``. Red-teaming one
asks which shapes break a planner that grasps by the object's live geometry, or by the nominal sizes it
reads from the env (peg, charger).

mplib needs numpy 1.x: every mplib wheel (0.1.0, 0.1.1, 0.2.1) crashes in ``Planner()`` under numpy 2. So
this policy runs only in simulator workers that import numpy 1.26 from their own folder first
(``worker_path``, :mod:`grt.evaluators.worker_env`), made once by ``python -m grt.setup motionplanning``; GRT's main
process builds the policy (a cheap object that checks the set-up) but never imports mplib.

Config (``conf/policy/motion_planner.yaml``)::

    _target_: grt.policies.motion_planner.MotionPlannerPolicy
    worker_path: ${paths.motionplanning}
    solution: auto          # ManiSkill's solution for the env id; or my_pkg.my_module:solve
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import io
import re
from collections.abc import Callable, Mapping
from pathlib import Path

from grt.errors import UserError
from grt.policies.base import EnvDriverPolicy

#: the one set-up command that makes the workers' numpy 1.26 (in a checkout also `make motionplanning`)
SETUP_COMMAND = "python -m grt.setup motionplanning"
#: where ManiSkill keeps its Panda solutions, one module per task (``pick_cube.py`` for ``PickCube-v1``)
SOLUTIONS = "mani_skill.examples.motionplanning.panda.solutions"


class MotionPlanningSetupError(UserError):
    """The motion planners' own numpy (or mplib) is not installed: one line naming the set-up command."""


class NoSolutionError(UserError):
    """An env for which ManiSkill has no motion-planning solution, or a ``solution`` that cannot be found."""


def seed_planner(seed: int) -> None:
    """Seed the random joint configurations of mplib's inverse kinematics for one episode.

    When its first IK attempt misses, mplib restarts from random configurations that pinocchio draws from the
    C library's ``rand()``: one stream per process, never seeded by ManiSkill's solutions. A trial's plan then
    depended on how many draws the plans its worker made before had taken (a failing trial re-ran as a
    success by ``grt.replay`` in a fresh process); seeded with the episode's seed, it depends on the episode.
    """
    import ctypes

    ctypes.CDLL(None).srand(ctypes.c_uint(seed % 2**32))


def _setup_missing(why: str) -> MotionPlanningSetupError:
    return MotionPlanningSetupError(f"policy=motion_planner needs mplib with numpy 1.26 in its simulator workers "
                                    f"(mplib crashes under numpy 2), and {why}: run `{SETUP_COMMAND}` once")


def check_setup(worker_path: str | list[str] | None) -> list[Path]:
    """The workers' folders, checked without importing anything from them: numpy 1.x is there, and mplib can
    be imported (from them or from GRT's environment, where ManiSkill installs it).

    Raises:
        MotionPlanningSetupError: no ``worker_path``, a folder missing, or no numpy 1.x or mplib found.
    """
    if not worker_path:
        raise _setup_missing("its config names no worker_path (the folder with that numpy: "
                             "worker_path: ${paths.motionplanning})")
    folders = [Path(p).expanduser() for p in ([worker_path] if isinstance(worker_path, str | Path) else worker_path)]
    for folder in folders:
        if not folder.is_dir():
            raise _setup_missing(f"{folder} does not exist")
    if not any(folder.glob("numpy-1.*.dist-info") for folder in folders):
        raise _setup_missing(f"{', '.join(map(str, folders))} holds no numpy 1.x")
    if importlib.util.find_spec("mplib") is None and not any((f / "mplib").is_dir() for f in folders):
        raise _setup_missing("mplib is not installed")
    return folders


def solution_module(env_id: str) -> str:
    """The module of ManiSkill's solution for ``env_id``: ``PegInsertionSide-v1`` ->
    ``...solutions.peg_insertion_side`` (an acronym stays one word: ``DrawSVG`` -> ``draw_svg``)."""
    name = env_id.split("-")[0]
    snake = re.sub(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])", "_", name).lower()
    return f"{SOLUTIONS}.{snake}"


def has_solution(env_id: str) -> bool:
    """Whether ManiSkill ships a solution for ``env_id`` (a file look-up: nothing is imported)."""
    spec = importlib.util.find_spec("mani_skill")
    if spec is None or not spec.submodule_search_locations:
        return False
    parts = solution_module(env_id).split(".")[1:]
    return any(Path(root, *parts[:-1], f"{parts[-1]}.py").is_file() for root in spec.submodule_search_locations)


def known_solutions() -> list[str]:
    """The env ids ManiSkill has solutions for (from its ``solutions/`` files), for messages."""
    spec = importlib.util.find_spec("mani_skill")
    roots = spec.submodule_search_locations if spec is not None else []
    names = []
    for root in roots or []:
        for path in sorted(Path(root, *SOLUTIONS.split(".")[1:]).glob("[a-z]*.py")):
            names.append("".join(w.upper() if w == "svg" else w.title() for w in path.stem.split("_")) + "-v1")
    return names


class MotionPlannerPolicy(EnvDriverPolicy):
    """ManiSkill's motion-planning solution of the env's task (or a user's ``solve(env, seed=...)``).

    The task session hands it its ManiSkill env once per trial: :meth:`solve` resets the env with the
    trial's seed and steps it to the end of the plan; the session then judges the final state.

    Args:
        worker_path: the folder(s) with numpy 1.26 that the workers running this policy import first (the
            evaluator reads it from the config; here it is only checked).
        solution: ``auto`` (ManiSkill's solution for the env id) or ``module:function`` (a function with the
            same signature, e.g. for a user's own env).
        quiet: keep the solutions' prints (a failed plan's status) out of the worker's output; the last one
            is returned as the trial's ``status`` instead.
        env_id, control_mode: the task's (the config interpolates them from ``task``): an env without a
            solution, or a control mode other than ``pd_joint_pos``, is refused here, before any simulation.
    """

    #: the control mode the solutions step the env in
    control_mode = "pd_joint_pos"

    def __init__(self, worker_path: str | list[str] | None = None, solution: str = "auto", quiet: bool = True,
                 env_id: str | None = None, control_mode: str | None = None):
        self.folders = check_setup(worker_path)
        self.solution, self.quiet = str(solution), bool(quiet)
        if self.solution != "auto" and ":" not in self.solution:
            raise NoSolutionError(f"policy.solution={self.solution}: give auto (ManiSkill's solution for the env) "
                                  "or module:function (a solve(env, seed=...) of your own)")
        if env_id:
            self.check_env(str(env_id), self.solution)
        if control_mode is not None:
            self.check_control_mode(str(control_mode))
        self._solve: Callable | None = None
        self._for: str | None = None

    @classmethod
    def check_config(cls, cfg: Mapping) -> None:
        """The constructor's checks of the task that need nothing built (:func:`grt.tasks.check_fit` runs them
        before the object is prepared): the task's control mode, and an env with a solution.

        Raises:
            NoSolutionError: as :meth:`check_control_mode` and :meth:`check_env`.
        """
        if cfg.get("control_mode") is not None:
            cls.check_control_mode(str(cfg["control_mode"]))
        if cfg.get("env_id"):
            cls.check_env(str(cfg["env_id"]), str(cfg.get("solution", "auto")))

    @classmethod
    def check_control_mode(cls, control_mode: str) -> None:
        """Refuse a task that steps the robot in another control mode than the solutions' ``pd_joint_pos``.

        Raises:
            NoSolutionError: naming both modes and the override that fixes it.
        """
        if control_mode != cls.control_mode:
            raise NoSolutionError(f"policy=motion_planner steps the robot in {cls.control_mode}, the task in "
                                  f"{control_mode}: add task.session.control_mode={cls.control_mode}")

    @staticmethod
    def check_env(env_id: str, solution: str = "auto") -> None:
        """Refuse an env without a solution before any simulation (a file look-up, no import).

        Raises:
            NoSolutionError: naming the env ids that have one.
        """
        if solution == "auto" and not has_solution(env_id):
            raise NoSolutionError(f"policy=motion_planner: ManiSkill has no motion-planning solution for {env_id} "
                                  f"(it has: {', '.join(known_solutions())}); give policy.solution=module:function "
                                  "for a solve(env, seed=...) of your own")

    def _function(self, env_id: str) -> Callable:
        if self._solve is not None and self._for == env_id:
            return self._solve
        import numpy

        if int(numpy.__version__.split(".")[0]) >= 2:  # mplib would crash the process: say why instead
            raise _setup_missing(f"this process runs numpy {numpy.__version__} (the evaluator's workers put "
                                 f"{', '.join(map(str, self.folders))} first on their path; call solve there)")
        if self.solution == "auto":
            self.check_env(env_id)
            module, name = solution_module(env_id), "solve"
        else:
            module, name = self.solution.split(":", 1)
        try:
            found = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError) as exc:
            raise NoSolutionError(f"policy.solution={module}:{name} cannot be loaded: {exc}") from exc
        self._solve, self._for = found, env_id
        return found

    def solve(self, env, seed: int) -> dict:
        """Run the solution on ``env`` (a ManiSkill env in ``pd_joint_pos``) for episode ``seed``.

        Returns:
            ``{"planned": bool, "status": str}``: whether every plan was found, and the planner's last
            message (``"ok"`` when it said nothing). The env is left at the plan's last step.
        """
        raw = env.unwrapped
        self.check_control_mode(str(raw.control_mode))
        spec = getattr(env, "spec", None) or raw.spec
        function = self._function(spec.id if spec is not None else type(raw).__name__)
        seed_planner(int(seed))
        out = io.StringIO()
        with contextlib.redirect_stdout(out) if self.quiet else contextlib.nullcontext():
            result = function(env, seed=int(seed))
        lines = [line for line in out.getvalue().splitlines() if line.strip()]
        planned = not (isinstance(result, int) and result == -1)
        return {"planned": planned, "status": lines[-1].strip() if lines else ("ok" if planned else "plan failed")}

    def reset(self, seed: int) -> None:
        """Nothing to reset: :meth:`solve` resets the env itself."""

    def __repr__(self) -> str:
        return f"MotionPlannerPolicy(solution={self.solution!r}, worker_path={[str(f) for f in self.folders]})"

