"""The grasp task session: one GRT-Grasp-v1 env per worker, seeded grasp-lift-shake trials.

An episode (the paper's protocol, appendix "Grasping Task"):

1. rebuild the scene and reset with the trial seed (object XY ±2 cm, yaw ±0.79 rad), let the
   object settle. Rebuilding (a ~30 ms reconfigure) makes a trial depend only on (object, seed):
   with a plain reset PhysX carries state over and the same seed ends millimeters apart after
   different predecessors (measured), which could flip a borderline trial;
2. render the depth cameras once, fuse the object's points, ask the policy for ranked grasps
   (``no_grasp_found`` if none);
3. solve IK for the via (12 cm back along the approach axis), pre-grasp (5 cm back), grasp, lift
   and shake poses of
   the best grasp that is reachable, trying each grasp also turned 180 deg about its approach axis
   (``unreachable`` if none);
4. move to the via pose, slide in to the pre-grasp, approach, close, lift 10 cm (``missed`` /
   ``dropped_lift``), shake 10 cm sideways and back (``dropped_shake``), and judge: object lifted
   and pinched by both fingers.

A trial is named (report.html shows these lines beside the modes, :func:`grt.tasks.base.mode_meanings`):

- ``success``: after the shake the object is still lifted and pinched between both fingers;
- ``no_grasp_found``: the policy planned no grasp on the object's point cloud;
- ``unreachable``: no planned grasp could be reached: none of the first ``max_ik_candidates`` grasps (each
  also turned 180 deg) had IK solutions for its via, pre-grasp, grasp, lift and shake poses, so the robot
  never moved towards the object;
- ``missed``: the fingers closed beside the object or lost it at once: it was not lifted;
- ``dropped_lift``: the object was pinched when the fingers closed but slipped out during the lift;
- ``dropped_shake``: the object was lifted but fell out of the fingers during the shake;
- ``sim_error``: a physics failure (NaN state, runaway object, a physics exception).

Any NaN, runaway object or physics exception ends the trial as ``sim_error``, and so does a policy's output
the task cannot use (a non-finite grasp pose or action, an action of the wrong shape), its reason naming the
policy (:class:`grt.policies.base.PolicyOutputError`).
"""

from __future__ import annotations

import gc
import time

import gymnasium as gym
import numpy as np

from grt.policies.base import GraspObservation, GraspStepPolicy, check_actions, check_grasps
from grt.tasks.base import COMMON_MODES, SUCCESS, Episodes, Objects, TaskSession, init_default
from grt.tasks.grasp_env import GraspEnv  # registers GRT-Grasp-v1 (env docstring: Description, ...)
from grt.tasks.motion import PandaIK, offset_along_approach, rotate_about_z, translated

__all__ = ["GraspEnv", "GraspSession", "SimError"]


class SimError(RuntimeError):
    """The simulation state became invalid (NaN, runaway object)."""


class GraspSession(TaskSession):
    """Grasp-lift-shake trials of one policy on one object at a time.

    Args:
        policy: a ``GraspPolicy`` (``plan(obs, seed) -> list[Grasp]``) or a ``GraspStepPolicy``.
        env_id: the registered ManiSkill env.
        num_cameras, camera_width, camera_height: the depth cameras (paper: 6 at 360 x 240).
        xy_range: object XY noise half-range (m); yaw_range: yaw noise half-range (rad).
        object_friction: friction coefficient of the object; object_density: kg/m^3.
        sim_freq, control_freq: physics and control rates (Hz).
        pregrasp_offset: approach distance (m) along the approach axis.
        lift_height: lift (m); shake_distance: lateral shake amplitude (m, world y).
        transit_offset: distance (m) along the approach axis of the via pose the arm first moves to;
            the hand then slides straight in, through space the grasp's collision check kept free.
        max_ik_candidates: ranked grasps tried for reachability before ``unreachable``.
        steps: control steps per phase: ``settle, transit, pregrasp, approach, close, lift, shake,
            hold``.
        max_policy_steps: step budget of a closed-loop policy.
    """

    #: the task's name, checked against a served policy's (grasp_2cam is this task with two cameras)
    task_name = "grasp"
    failure_modes = (*COMMON_MODES, "no_grasp_found", "unreachable", "missed", "dropped_lift", "dropped_shake")
    policy_kinds = ("grasp_planner", "grasp_step")
    # worst cases (s) measured at a load average of 13 on 2 cores (scripts/step_times.py), rounded up: a control
    # step 37 ms on average; the scene rebuilt 0.51 s at most; the capture 30 s for 6 cameras of 360 x 240 in a
    # worker's first trial (it builds the renderer's shaders; 0.3-1 s after), per camera; a planning of the
    # slowest shipped planner, Contact-GraspNet, 14.4 s at most (antipodal: 1.2 s), with room for a retry
    STEP_S, RESET_S, CAPTURE_S, PLAN_S = 0.04, 0.5, 5.0, 30.0

    @classmethod
    def trial_seconds(cls, **session_kwargs) -> float:
        """Reset, capture and plan, then every phase's control steps and a step policy's step budget at the
        measured worst cases (see :meth:`grt.tasks.base.TaskSession.trial_seconds`)."""
        steps = sum(int(n) for n in session_kwargs.get("steps") or init_default(cls, "steps"))
        steps += int(session_kwargs.get("max_policy_steps") or init_default(cls, "max_policy_steps"))
        cameras = int(session_kwargs.get("num_cameras") or init_default(cls, "num_cameras"))
        pixels = int(session_kwargs.get("camera_width") or init_default(cls, "camera_width")) * \
            int(session_kwargs.get("camera_height") or init_default(cls, "camera_height"))
        capture = cls.CAPTURE_S * cameras * max(1.0, pixels / (360 * 240))
        return cls.RESET_S + capture + cls.PLAN_S + steps * cls.STEP_S

    def __init__(self, policy, env_id: str = "GRT-Grasp-v1", num_cameras: int = 6, camera_width: int = 360,
                 camera_height: int = 240, xy_range: float = 0.02, yaw_range: float = 0.79,
                 object_friction: float = 1.0, object_density: float = 500.0, sim_freq: int = 100,
                 control_freq: int = 20, pregrasp_offset: float = 0.05, lift_height: float = 0.10,
                 shake_distance: float = 0.10, transit_offset: float = 0.12, max_ik_candidates: int = 10,
                 steps: tuple[int, ...] = (6, 12, 6, 8, 6, 10, 6, 3), max_policy_steps: int = 100):
        self.policy = policy
        self.pregrasp_offset, self.lift_height = float(pregrasp_offset), float(lift_height)
        self.shake_distance, self.max_ik_candidates = float(shake_distance), int(max_ik_candidates)
        self.transit_offset = float(transit_offset)
        names = ("settle", "transit", "pregrasp", "approach", "close", "lift", "shake", "hold")
        self.steps = dict(zip(names, (int(s) for s in steps), strict=True))
        self.max_policy_steps = int(max_policy_steps)
        self._sim_steps, self._sim_s = 0, 0.0
        self._planned: dict[int, tuple] = {}  # seed -> (grasps, capture_s, num_points, plan_s)
        self.env = gym.make(env_id, obs_mode="none", control_mode="pd_joint_pos", sim_backend="physx_cpu",
                            render_backend="cpu", num_cameras=num_cameras, camera_width=camera_width,
                            camera_height=camera_height, xy_range=xy_range, yaw_range=yaw_range,
                            object_friction=object_friction, object_density=object_density,
                            sim_freq=sim_freq, control_freq=control_freq, evaluate_every_step=False,
                            reward_mode="none")
        self.env.reset(seed=0)
        self.ik = PandaIK(self.unwrapped.agent.robot)
        # ManiSkill's reconfigure runs gc.collect(); freezing the long-lived objects makes it cheap.
        gc.collect()
        gc.freeze()

    @property
    def unwrapped(self):
        return self.env.unwrapped

    def load_objects(self, objects: Objects, assignment) -> None:
        """The object (meters) of the session's one sub-scene and its convex parts; the scene is rebuilt."""
        mesh, parts = objects[int(assignment[0])]
        if mesh is None:
            raise ValueError("the grasp task has no stock object: give it a mesh and its convex parts")
        self._planned.clear()
        self.unwrapped.set_object(mesh, parts)
        self.env.reset(seed=0, options=dict(reconfigure=True))
        self.ik = PandaIK(self.unwrapped.agent.robot)

    def close(self) -> None:
        self.env.close()

    def render(self, path: str) -> None:
        """Write a PNG of the scene as it is now (after a trial: its final state), 512 x 512."""
        from PIL import Image

        image = self.unwrapped.render_rgb_array()
        Image.fromarray(np.asarray(image[0], dtype=np.uint8)).save(path)

    def _play(self, episodes: Episodes) -> None:
        """The episode of the session's one sub-scene (see the module docstring)."""
        info = episodes.info[0]
        self._sim_steps, self._sim_s = 0, 0.0
        try:
            mode = self._episode(episodes.seeds[0], info)
        finally:  # after a failure too: the simulated steps, their seconds, where the object ended up
            episodes.steps[0] = self._sim_steps
            info["sim_s"], info["object_final"] = self._sim_s, self._final_position()
        episodes.end(0, mode, float(mode == SUCCESS))

    # --- episode -------------------------------------------------------------------------------------
    def _episode(self, seed: int, info: dict) -> str:
        self._settle(seed)
        info["placement"] = dict(self.unwrapped.placement)
        self._check_health()
        motion = self._motion()  # a shape that cannot stand is still falling here, when the policy looks
        info.update(tilt_deg=motion["tilt_deg"], spin_dps=motion["spin_dps"])
        self._rest_z = self._object_pose()[2]
        if seed in self._planned:  # planned ahead in a batch (prefetch): the same cloud, the same grasps
            grasps, info["capture_s"], info["num_points"], info["plan_s"] = self._planned.pop(seed)
            info["batched"] = True
        else:
            t = time.perf_counter()
            obs = self._observe()
            info["capture_s"], info["num_points"] = time.perf_counter() - t, len(obs.points)
            if isinstance(self.policy, GraspStepPolicy):
                return self._closed_loop(seed, obs.points, obs.viewpoints, info)
            t = time.perf_counter()
            grasps = self.policy.plan(obs, seed)
            info["plan_s"] = time.perf_counter() - t
        grasps = check_grasps(grasps, self.policy)  # a NaN pose: a sim_error naming the policy, never `missed`
        info["num_grasps"] = len(grasps)
        if not grasps:
            return "no_grasp_found"
        plan = self._reachable_plan(grasps, info)
        if plan is None:
            return "unreachable"
        q_via, q_pre, q_grasp, grasp_pose = plan
        self._move(q_via, self.steps["transit"])
        self._move(q_pre, self.steps["pregrasp"])
        self._move(q_grasp, self.steps["approach"])
        return self._close_lift_shake(grasp_pose, info)

    def observe(self, seed: int) -> GraspObservation:
        """What the policy sees in trial ``seed``: the scene rebuilt from the seed, settled, captured."""
        self._settle(int(seed))
        return self._observe()

    def rest_pose(self, seed: int, hold: int = 0) -> dict:
        """Trial ``seed``'s scene rebuilt and settled as a trial settles it, before the policy acts: where the
        object is (``position``, m), how far it tipped (``tilt_deg``: its up axis against the world's; it is
        placed upright) and whether it still moves (``speed_mps``, ``spin_dps``); with ``hold`` > 0 control
        steps more, ``held_tilt_deg``: where it ends up. A shape that cannot stand fails every grasp policy."""
        self._settle(int(seed))
        out = {"position": self._object_pose().round(6).tolist(), **self._motion()}
        if hold > 0:
            self._move(self._target, int(hold))
            out["held_tilt_deg"] = self._motion()["tilt_deg"]
        return out

    def _motion(self) -> dict:
        """The object's tilt (deg between its up axis and the world's; 0: upright, as placed), speed (m/s) and
        spin (deg/s) now."""
        obj = self.unwrapped.obj
        _, x, y, _ = obj.pose.q[0].numpy().astype(np.float64)  # (w, x, y, z)
        tilt = np.degrees(np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y), -1.0, 1.0)))
        return {"tilt_deg": round(float(tilt), 2),
                "speed_mps": round(float(np.linalg.norm(obj.linear_velocity[0].numpy())), 4),
                "spin_dps": round(float(np.degrees(np.linalg.norm(obj.angular_velocity[0].numpy()))), 2)}

    def _settle(self, seed: int) -> None:
        """Rebuild trial ``seed``'s scene (a trial depends only on object and seed) and let it come to rest."""
        self.env.reset(seed=seed, options=dict(reconfigure=True))
        self._target, self._gripper = self._qpos(), 1.0
        self._move(self._target, self.steps["settle"])

    def _observe(self) -> GraspObservation:
        """Render the cameras: the object's cloud (and the table around it if the policy asks)."""
        radius = float(getattr(self.policy, "context_radius", 0.0) or 0.0)
        if radius > 0:
            points, views, context = self.unwrapped.capture_scene_cloud(radius)
            return GraspObservation(points, views, table_z=0.0, context=context)
        points, views = self.unwrapped.capture_object_cloud()
        return GraspObservation(points, views, table_z=0.0)

    def prefetch(self, seeds) -> None:
        """Plan the grasps of the coming trials in batches, for a policy with ``plan_batch``.

        Each trial's scene is rebuilt from its seed and settled, as the trial itself will do (a trial
        depends only on (object, seed)), its cloud captured; then one batched inference per
        ``policy.batch_size`` trials. :meth:`run_trial` uses the stored grasps.
        """
        size = int(getattr(self.policy, "batch_size", 1) or 1)
        if size <= 1 or not hasattr(self.policy, "plan_batch") or isinstance(self.policy, GraspStepPolicy):
            return
        seeds = [int(s) for s in seeds if int(s) not in self._planned]
        for start in range(0, len(seeds), size):
            chunk, observations, capture = seeds[start:start + size], [], []
            for seed in chunk:
                self._settle(seed)
                t = time.perf_counter()
                observations.append(self._observe())
                capture.append(time.perf_counter() - t)
            t = time.perf_counter()
            plans = self.policy.plan_batch(observations, chunk)
            plan_s = (time.perf_counter() - t) / len(chunk)
            for seed, obs, grasps, cap in zip(chunk, observations, plans, capture, strict=True):
                self._planned[seed] = (grasps, cap, len(obs.points), plan_s)

    def _reachable_plan(self, grasps, info: dict):
        """(q_via, q_pregrasp, q_grasp, pose) of the best grasp whose motion has IK solutions, or None."""
        q0 = self._qpos()
        for rank, grasp in enumerate(grasps[: self.max_ik_candidates]):
            options = []
            for flip in (0.0, np.pi):
                pose = rotate_about_z(grasp.pose, flip)
                q_via = self.ik.solve(offset_along_approach(pose, -self.transit_offset), q0)
                q_pre = None if q_via is None else self.ik.solve(
                    offset_along_approach(pose, -self.pregrasp_offset), q_via)
                q_grasp = None if q_pre is None else self.ik.solve(pose, q_pre)
                if q_grasp is None or self._lift_shake_joints(pose, q_grasp) is None:
                    continue
                if np.abs(q_grasp - q_via)[:7].max() > 0.8:  # IK jumped branches: no straight approach
                    continue
                options.append((np.abs(q_via - q0)[:7].sum(), q_via, q_pre, q_grasp, pose))
            if options:
                _, q_via, q_pre, q_grasp, pose = min(options, key=lambda o: o[0])
                info.update(grasp_rank=rank, grasp_score=grasp.score, grasp_width=grasp.width,
                            approach_z=float(pose[2, 2]))
                return q_via, q_pre, q_grasp, pose
        return None

    def _lift_shake_joints(self, pose: np.ndarray, q_grasp: np.ndarray):
        lift_pose = translated(pose, np.array([0.0, 0.0, self.lift_height]))
        q_lift = self.ik.solve(lift_pose, q_grasp)
        if q_lift is None:
            return None
        q_shake = self.ik.solve(translated(lift_pose, np.array([0.0, self.shake_distance, 0.0])), q_lift)
        return None if q_shake is None else (q_lift, q_shake)

    def _close_lift_shake(self, grasp_pose: np.ndarray, info: dict) -> str:
        q_grasp = self._target.copy()
        self._gripper = -1.0
        self._move(q_grasp, self.steps["close"])
        self._check_health()
        info["grasped_after_close"] = held_at_close = self._pinched()
        joints = self._lift_shake_joints(grasp_pose, self._qpos())
        if joints is None:
            return "unreachable"
        q_lift, q_shake = joints
        self._move(q_lift, self.steps["lift"])
        self._move(q_lift, self.steps["hold"])
        self._check_health()
        if not self._held():
            return "dropped_lift" if held_at_close else "missed"
        self._move(q_shake, self.steps["shake"])
        self._move(q_lift, self.steps["shake"])
        self._move(q_lift, self.steps["hold"])
        self._check_health()
        return "success" if self._held() else "dropped_shake"

    def _closed_loop(self, seed: int, points: np.ndarray, views: np.ndarray, info: dict) -> str:
        self.policy.reset(seed)
        for step in range(self.max_policy_steps):
            tcp = self.unwrapped.agent.tcp.pose.sp.to_transformation_matrix()
            obs = dict(qpos=self._qpos(), tcp_pose=tcp, points=points, viewpoints=views, step=step)
            action = self.policy.act(obs)
            if action is None:
                break
            action = check_actions(action, (8,), self.policy)
            self._target, self._gripper = np.concatenate([action[:7], self._target[7:]]), float(action[7])
            self._move(self._target, 1)
        self._check_health()
        tcp = self.unwrapped.agent.tcp.pose.sp.to_transformation_matrix()
        return self._close_lift_shake(tcp, info)

    # --- simulation helpers --------------------------------------------------------------------------
    def _qpos(self) -> np.ndarray:
        return self.unwrapped.agent.robot.get_qpos()[0].numpy().astype(np.float64)

    def _object_pose(self) -> np.ndarray:
        return self.unwrapped.obj.pose.p[0].numpy().astype(np.float64)

    def _final_position(self) -> list[float] | None:
        """The object's position (x, y, z; m) now, ``None`` when the scene itself is what failed."""
        try:
            return self._object_pose().round(6).tolist()
        except Exception:  # noqa: BLE001
            return None

    def _move(self, q_to: np.ndarray, steps: int) -> None:
        """Smoothstep joint interpolation from the last target to ``q_to`` over ``steps`` control steps."""
        q_from, start = self._target, time.perf_counter()
        for k in range(1, steps + 1):
            s = k / steps
            q = q_from + (q_to - q_from) * (3 * s * s - 2 * s * s * s)
            self.env.step(np.concatenate([q[:7], [self._gripper]]).astype(np.float32))
        self._target = np.asarray(q_to, np.float64).copy()
        self._sim_steps += steps
        self._sim_s += time.perf_counter() - start

    def _pinched(self) -> bool:
        return bool(self.unwrapped.agent.is_grasping(self.unwrapped.obj)[0])

    def _held(self) -> bool:
        lifted = self._object_pose()[2] - self._rest_z > 0.5 * self.lift_height
        return bool(lifted and self._pinched())

    def _check_health(self) -> None:
        p, q = self._object_pose(), self._qpos()
        speed = float(np.linalg.norm(self.unwrapped.obj.linear_velocity[0].numpy()))
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q)) and np.isfinite(speed)):
            raise SimError("non-finite object or robot state")
        if np.abs(p[:2]).max() > 1.0 or p[2] < -0.05 or p[2] > 1.0 or speed > 5.0:
            raise SimError(f"object ran away: position {p.round(3).tolist()}, speed {speed:.2f} m/s")
