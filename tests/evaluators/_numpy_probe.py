"""A session that reports which numpy its worker runs and what crossed the pipe (the worker-path tests).

Imported by spawned workers that may run numpy 1.26 (``worker_path``): nothing here may need numpy 2.
"""

from __future__ import annotations

import numpy as np

from grt.tasks.base import TaskSession


class ProbePolicy:
    """A policy config with ``worker_path`` (the evaluator reads it; the class is given it too)."""

    def __init__(self, worker_path=None):
        self.worker_path = worker_path


class ProbeSession(TaskSession):
    """Sums the job's geometry; each trial answers with numpy objects of this worker's numpy."""

    def __init__(self, policy: ProbePolicy):
        self.policy, self.total = policy, None

    def load_objects(self, objects, assignment) -> None:
        mesh, parts = objects[assignment[0]]
        self.total = float(np.sum(mesh.vertices)) + float(np.sum(mesh.faces)) + sum(float(np.sum(p)) for p in parts)

    def _play(self, episodes) -> None:
        seed = episodes.seeds[0]  # a 0-d array: a float would be rounded to 6 digits in the outcome's info
        episodes.end(0, "success", np.float64(seed) / 10, {"numpy": np.__version__, "total": np.asarray(self.total),
                                                          "array": np.arange(3.0) * seed,
                                                          "ints": np.arange(2, dtype=np.int32)})


def numpy_version(offset: float) -> tuple[str, float]:
    """What :func:`grt.evaluators.worker_env.run_in_worker` runs in the tests: this process's numpy, and a sum."""
    return np.__version__, float(np.sum(np.arange(4.0)) + offset)


def refuse(reason: str) -> None:
    from grt.errors import UserError

    raise UserError(reason)


_PLANNER = []


def _planner():
    """mplib's planner for the Panda (numpy 1.26), made once per process."""
    import os

    import mani_skill
    import mplib

    if not _PLANNER:
        urdf = os.path.join(os.path.dirname(mani_skill.__file__), "assets", "robots", "panda", "panda_v2.urdf")
        _PLANNER.append(mplib.Planner(urdf=urdf, srdf=urdf.replace(".urdf", ".srdf"), move_group="panda_hand_tcp"))
    return _PLANNER[0]


def first_restart(env, seed):
    """A ``solve(env, seed=...)``: prints the first random configuration mplib's IK would restart from."""
    print(" ".join(f"{q:.6f}" for q in _planner().pinocchio_model.get_random_configuration()))
    return 0


class _Env:
    """Just what :meth:`MotionPlannerPolicy.solve` reads of an env."""

    class unwrapped:  # noqa: N801 - the env attribute's name
        control_mode = "pd_joint_pos"
        spec = None

    spec = None


def ik_restarts(worker_path: str, seed: int, draws_before: int) -> str:
    """The first random IK restart of an episode seeded ``seed`` that ``MotionPlannerPolicy.solve`` runs
    (``first_restart`` as its solution), after ``draws_before`` draws by earlier plans of the same process."""
    from grt.policies.motion_planner import MotionPlannerPolicy

    policy = MotionPlannerPolicy(worker_path=worker_path, solution="_numpy_probe:first_restart")
    for _ in range(draws_before):
        _planner().pinocchio_model.get_random_configuration()
    return policy.solve(_Env(), seed)["status"]
