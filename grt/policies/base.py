"""Policy interfaces of GRT: black boxes the tasks call, chosen by ``_target_`` in ``conf/policy``.

Two kinds of policy plug into the grasp task (:class:`grt.tasks.grasp.GraspSession`):

1. **Grasp planners** (open loop, like the paper's Contact-GraspNet): :class:`GraspPolicy` maps one
   observation of the object (a fused point cloud) to ranked 6-D grasps; the task executes the best
   reachable one (IK, approach, close, lift, shake). To bring your own predictor, implement
   :class:`GraspPredictor` and wrap it in :class:`PointCloudGraspPolicy`::

       # conf/policy/my_predictor.yaml
       _target_: grt.policies.base.PointCloudGraspPolicy
       predictor:
         _target_: my_package.MyPredictor   # predict(points (P,3), normals (P,3), rng) -> list[Grasp]
       max_retries: 10

2. **Step-by-step grasp policies**: :class:`GraspStepPolicy` gets an observation dict every control
   step and returns a ``pd_joint_pos`` action until it is done; the task then lifts and shakes to judge
   the grasp::

       # conf/policy/my_policy.yaml
       _target_: my_package.MyPolicy          # a GraspStepPolicy subclass

The episode tasks (insertion, drawer: :class:`grt.tasks.base.EpisodeSession`) run a
:class:`BatchedPolicy` instead: observation groups in, actions out, batched, every control step.

Frames and units: world frame, meters, z up, table top at ``table_z``. A grasp pose is the
tool-center-point (TCP, between the fingertips) pose: its z axis is the approach direction (from
the palm towards the object), its y axis the closing direction of the fingers.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

from grt.errors import UserError
from grt.policies.pointcloud import oriented_cloud


@dataclass
class Grasp:
    """A parallel-jaw grasp.

    Attributes:
        pose: ``(4, 4)`` world-frame TCP pose (z = approach, y = closing axis), meters.
        width: distance (m) between the two contacts.
        score: higher is better; only the order matters.
        info: predictor-specific details (e.g. antipodality, contact points).
    """

    pose: np.ndarray
    width: float
    score: float
    info: dict = field(default_factory=dict)


@dataclass
class GraspObservation:
    """What a grasp planner sees once per trial.

    Attributes:
        points: ``(P, 3)`` segmented object points, world frame (m).
        viewpoints: ``(P, 3)`` position (m) of the camera that saw each point (orients normals).
        table_z: height (m) of the table top.
        context: ``(Q, 3)`` points (m, world) of the table top around the object, for planners that
            ask for them (``context_radius > 0``); ``None`` otherwise.
    """

    points: np.ndarray
    viewpoints: np.ndarray
    table_z: float = 0.0
    context: np.ndarray | None = None


class BatchedPolicy(ABC):
    """A black-box closed-loop policy of the episode tasks, behind one small batched interface.

    The task owns the observation adapter: it hands the policy a dict of named observation groups,
    each batched along the first axis (``(N, ...)``), and applies the returned actions ``(N, A)`` in
    [-1, 1]. The same class serves every task whose observations it understands: an rsl-rl
    checkpoint (:class:`grt.policies.rsl_rl.RslRlPolicy`) for insertion or the drawer, or a user's
    class with these two methods.
    """

    def reset(self, seed: int) -> None:  # noqa: B027 - optional hook
        """Start a new episode (recurrent state, per-episode randomness seeded by ``seed``)."""

    @abstractmethod
    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """Actions ``(N, A)`` for a batch of observations ``{group: (N, ...)}``."""


class PolicyServerError(UserError):
    """A policy in another process that cannot be reached, refuses the connection, is made for another
    task, or went away for good (:mod:`grt.policies.remote`): one line naming it, exit code 2."""


class PolicyInterrupted(BaseException):
    """The policy lost its state in the middle of a trial (its server went away): the trial did not fail,
    it is re-run from its start (the evaluator's worker does it). A ``BaseException``, so that the trial's
    own ``except Exception`` (which records a ``sim_error``) does not judge it."""


class PolicyUnavailable(BaseException):
    """The policy cannot answer any more (its server stayed down): the evaluation stops, nothing is
    judged, and the run can be finished later (``resume=DIR``). A ``BaseException`` for the same reason."""


class PolicyOutputError(RuntimeError):
    """A policy's output the task cannot use: non-finite numbers (a NaN grasp pose or action) or actions of
    the wrong shape. Raised in the trial, which becomes a ``sim_error`` whose reason names the policy (never a
    physical outcome such as ``missed``); the red-team run and ``grt.evaluate`` stop in one line when every
    trial on the object ends so (:func:`grt.evaluators.base.check_scored`)."""


def policy_name(policy) -> str:
    """``module.Class`` of a policy (and what a served one calls itself), for messages; a wrapper of a predictor
    (:class:`PointCloudGraspPolicy`) is named by the predictor, whose output it passes on."""
    inner = getattr(policy, "predictor", None)
    if inner is not None and getattr(type(policy), "plan", None) is PointCloudGraspPolicy.plan:  # passed on as is
        return f"{_qualified(inner)} (through {_qualified(policy)})"
    name = getattr(policy, "name", None)
    return _qualified(policy) + (f" ({name})" if isinstance(name, str) and name else "")


def _qualified(obj) -> str:
    cls = type(obj)
    return f"{cls.__module__}.{cls.__qualname__}"


def check_actions(actions, shape: tuple[int, ...], policy) -> np.ndarray:
    """``actions`` as an array of ``shape``, finite (float64).

    Raises:
        PolicyOutputError: another shape, or a NaN/inf (names the policy, what it returned and what the task takes).
    """
    try:
        out = np.asarray(actions, np.float64)
    except (TypeError, ValueError) as err:
        raise PolicyOutputError(f"policy {policy_name(policy)} returned {type(actions).__name__} ({err}), not "
                                f"actions of shape {shape}") from None
    if out.shape != tuple(shape):
        raise PolicyOutputError(f"policy {policy_name(policy)} returned actions of shape {out.shape}; the task "
                                f"takes {tuple(shape)}: fix the policy's act()")
    if not np.all(np.isfinite(out)):
        raise PolicyOutputError(f"policy {policy_name(policy)} returned a non-finite action {out.round(4).tolist()}")
    return out


def check_grasps(grasps, policy) -> list[Grasp]:
    """A grasp planner's ``grasps``, each with a finite ``(4, 4)`` pose, width and score.

    Raises:
        PolicyOutputError: names the policy and the grasp.
    """
    for i, grasp in enumerate(grasps):
        try:
            pose, width, score = np.asarray(grasp.pose, np.float64), float(grasp.width), float(grasp.score)
        except (AttributeError, TypeError, ValueError) as err:
            raise PolicyOutputError(f"policy {policy_name(policy)} returned grasp {i} that is no Grasp(pose, width, "
                                    f"score) ({err})") from None
        if pose.shape != (4, 4):
            raise PolicyOutputError(f"policy {policy_name(policy)} returned grasp {i} with a pose of shape "
                                    f"{pose.shape}, not (4, 4)")
        if not (np.all(np.isfinite(pose)) and np.isfinite(width) and np.isfinite(score)):
            raise PolicyOutputError(f"policy {policy_name(policy)} returned a non-finite grasp (grasp {i}: pose "
                                    f"{pose.round(4).tolist()}, width {width}, score {score})")
    return list(grasps)


class GraspPredictor(ABC):
    """A point-cloud grasp predictor (one inference)."""

    @abstractmethod
    def predict(self, points: np.ndarray, normals: np.ndarray, rng: np.random.Generator,
                table_z: float = 0.0) -> list[Grasp]:
        """Propose grasps on a cloud.

        Args:
            points: ``(P, 3)`` object points (m, world).
            normals: ``(P, 3)`` unit outward normals.
            rng: the trial's random generator (deterministic given the trial seed).
            table_z: height (m) of the table top (for collision checks).

        Returns:
            Grasps sorted best first; empty if none passed the predictor's checks.
        """


class GraspPolicy(ABC):
    """Open-loop grasp planner: observation -> ranked grasps, executed by the task."""

    @abstractmethod
    def plan(self, obs: GraspObservation, seed: int) -> list[Grasp]:
        """Ranked grasps (best first) for one trial; empty means ``no_grasp_found``."""


class PointCloudGraspPolicy(GraspPolicy):
    """Downsample, estimate normals (camera by camera), run a :class:`GraspPredictor`, retry while it
    finds nothing.

    Args:
        predictor: the grasp predictor.
        max_retries: inferences before giving up (the paper retries Contact-GraspNet up to 10 times).
        voxel_size: voxel (m) of the downsampled cloud.
        normal_neighbors: neighbors per point of the PCA normal estimate.
    """

    def __init__(self, predictor: GraspPredictor, max_retries: int = 10, voxel_size: float = 0.004,
                 normal_neighbors: int = 12):
        self.predictor = predictor
        self.max_retries, self.voxel_size = int(max_retries), float(voxel_size)
        self.normal_neighbors = int(normal_neighbors)

    def plan(self, obs: GraspObservation, seed: int) -> list[Grasp]:
        if len(obs.points) < self.normal_neighbors:
            return []
        points, normals = oriented_cloud(obs.points, obs.viewpoints, self.voxel_size, self.normal_neighbors)
        if len(points) < self.normal_neighbors:
            return []
        rng = np.random.default_rng(seed)
        for attempt in range(self.max_retries):
            grasps = self.predictor.predict(points, normals, rng, table_z=obs.table_z)
            if grasps:
                for g in grasps:
                    g.info["attempt"] = attempt
                return grasps
        return []


class GraspStepPolicy(ABC):
    """A grasp policy that acts every control step, one observation at a time, until it is done (the
    grasp task then judges the grasp by lifting and shaking).

    ``obs`` holds ``qpos`` (9,) joint positions (rad, fingers in m), ``tcp_pose`` (4, 4),
    ``points`` / ``viewpoints`` (P, 3) of the object cloud (captured once per trial) and ``step``.
    """

    def reset(self, seed: int) -> None:  # noqa: B027 - optional hook
        """Start a new trial."""

    @abstractmethod
    def act(self, obs: dict) -> np.ndarray | None:
        """A ``pd_joint_pos`` action (8,): 7 arm joint targets (rad) + gripper in [-1 closed, 1 open];
        ``None`` when done (the task then lifts and shakes)."""


class EnvDriverPolicy(ABC):
    """A policy that drives a ManiSkill env itself, e.g. ManiSkill's motion-planning solutions: it gets the
    task's gymnasium env with the candidate already in it, may ``reset(seed=seed)`` it (the same episode:
    the candidate is installed and settled inside the env's own reset) and steps it as it likes. The task
    judges the trial from the steps it took (:class:`grt.tasks.maniskill.session.ManiSkillSession`)."""

    def reset(self, seed: int) -> None:  # noqa: B027 - optional hook
        """Start a new trial."""

    @abstractmethod
    def solve(self, env, seed: int):
        """Run one episode of ``env`` (a gymnasium env over a ManiSkill ``BaseEnv``) from ``seed``.

        Returns:
            Optionally ``{"planned": bool, "status": str}`` (or ``-1``, ManiSkill's solutions' "no plan"): a
            failure without a plan is the trial's ``no_plan``, and a status other than ``ok`` is kept with the
            trial (``note`` in the journal and ``evaluation.json``); anything else is ignored.
        """


#: the kinds of policy a task can drive, in words (:func:`policy_kind`; a task session names those it
#: runs in ``TaskSession.policy_kinds``, and :func:`grt.tasks.preflight` refuses another kind).
POLICY_KINDS = {
    "grasp_planner": "a grasp planner (one point cloud in, ranked grasps out: GraspPolicy.plan)",
    "grasp_step": "a step-by-step grasp policy (GraspStepPolicy: one observation in, one arm action out)",
    "closed_loop": "a closed-loop policy (BatchedPolicy: observation groups in, actions out, every control step)",
    "env_driver": "a policy that drives the env itself (EnvDriverPolicy.solve(env, seed), e.g. a motion planner)",
}


def policy_kind(cls: type) -> str | None:
    """The kind of a policy class (a key of :data:`POLICY_KINDS`), or ``None`` when it is none of them.

    A subclass of one of the interfaces is of its kind; a class that subclasses none is taken by what it
    has, as the tasks call it: ``solve`` (an env driver), ``plan`` (a grasp planner) or ``act`` (a closed-loop
    policy).
    """
    if issubclass(cls, GraspStepPolicy):
        return "grasp_step"
    if issubclass(cls, GraspPolicy):
        return "grasp_planner"
    if issubclass(cls, BatchedPolicy):
        return "closed_loop"
    if issubclass(cls, EnvDriverPolicy) or callable(getattr(cls, "solve", None)):
        return "env_driver"
    if callable(getattr(cls, "plan", None)):
        return "grasp_planner"
    if callable(getattr(cls, "act", None)):
        return "closed_loop"
    return None


def observation_groups(spec: dict, limit: int = 6) -> str:
    """A task's observation groups as words for a message (``state (35,), cloud (500, 3)``), the first
    ``limit`` of them."""
    text = ", ".join(f"{g} {tuple(v)}" for g, v in list(spec.items())[:limit]) or "none"
    return text + (f" and {len(spec) - limit} more" if len(spec) > limit else "")
