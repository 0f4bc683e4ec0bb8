"""rsl-rl's ``VecEnv`` over GRT task sessions: the same environment for training and red-teaming.

On the CPU backend ManiSkill holds one environment per scene, so :class:`TaskVecEnv` runs
``num_envs`` :class:`grt.tasks.base.EpisodeSession` objects spread over ``workers`` processes (each
process steps its share in turn; ``workers=0`` keeps them in this process, for tests and debugging).
Every env resets itself when its episode ends (success or time limit), drawing the next episode's
shape from ``shapes`` (the nominal object and, for blue-teaming, CrashShapes) with ``weights``, and
its next seed from its own stream, so a training run is reproducible given ``seed``.

Observations are a ``TensorDict`` of the session's groups (``state`` (N, 24), ``cloud`` (N, P, 3));
``extras["time_outs"]`` marks time-limit ends (bootstrapped by PPO) and ``extras["log"]`` carries the
success rate and mean length of the episodes that ended in the step.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import traceback
from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from grt.evaluators.pool import build_session
from grt.targets import build_error, worker_error
from grt.tasks import session_class


@dataclass
class Shape:
    """One object an env can draw: mesh (meters) and convex parts ``(K, 3)``."""

    vertices: np.ndarray
    faces: np.ndarray
    parts: list[np.ndarray]
    name: str = "nominal"

    @classmethod
    def of(cls, mesh: trimesh.Trimesh, parts: list[np.ndarray], name: str = "nominal") -> Shape:
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.faces), [np.asarray(p) for p in parts], name)

    def mesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices, self.faces, process=False)


class _EnvGroup:
    """The sessions of one worker: step them in turn, reset the finished ones."""

    def __init__(self, task: dict, shapes: list[Shape], weights: np.ndarray, env_ids: list[int], seed: int,
                 max_steps: int | None):
        self.shapes, self.weights = shapes, weights
        self.sessions, self.current = [], []
        for _ in env_ids:
            session = build_session(task, None)
            if max_steps:
                session.max_steps = int(max_steps)
            self.sessions.append(session)
            self.current.append(-1)
        self.rngs = [np.random.default_rng([seed, i]) for i in env_ids]
        self.returns = np.zeros(len(env_ids))

    def _new_episode(self, k: int) -> dict:
        rng = self.rngs[k]
        index = int(rng.choice(len(self.shapes), p=self.weights))
        if index != self.current[k]:
            shape = self.shapes[index]
            self.sessions[k].load_object(shape.mesh(), shape.parts)
            self.current[k] = index
        self.returns[k] = 0.0
        for attempt in range(3):  # a start the robot cannot reach (IK) is skipped, not fatal
            try:
                return self.sessions[k].reset(int(rng.integers(2**31 - 1)))
            except RuntimeError:
                if attempt == 2:
                    raise
        raise AssertionError("unreachable")

    def reset(self) -> list[dict]:
        return [self._new_episode(k) for k in range(len(self.sessions))]

    def step(self, actions: np.ndarray):
        obs, rew, term, trunc, ended = [], [], [], [], []
        for k, session in enumerate(self.sessions):
            o, r, te, tr, info = session.step(actions[k])
            self.returns[k] += r
            if te or tr:
                ended.append(dict(success=bool(info["success"]), length=session.steps,
                                  shape=self.shapes[self.current[k]].name, ret=float(self.returns[k])))
                o = self._new_episode(k)
            obs.append(o)
            rew.append(r)
            term.append(te)
            trunc.append(tr and not te)
        return obs, np.array(rew, np.float32), np.array(term), np.array(trunc), ended

    def close(self) -> None:
        for s in self.sessions:
            s.close()


def _worker(conn, task, shapes, weights, env_ids, seed, max_steps, threads):
    torch.set_num_threads(threads)
    try:
        group = _EnvGroup(task, shapes, weights, env_ids, seed, max_steps)
    except Exception:  # noqa: BLE001 - the main process words it in one line (grt.targets.worker_error)
        conn.send(("fatal", traceback.format_exc()))
        conn.close()
        return
    conn.send(("ready", None))
    try:
        while True:
            cmd, payload = conn.recv()
            if cmd == "reset":
                conn.send(group.reset())
            elif cmd == "step":
                conn.send(group.step(payload))
            elif cmd == "close":
                break
    finally:
        group.close()
        conn.close()


class TaskVecEnv(VecEnv):
    """rsl-rl ``VecEnv`` of ``num_envs`` sessions of one task (see the module docstring).

    Args:
        task: the task config as a plain dict (``task["session"]`` builds a session with ``policy=None``).
        shapes: the objects episodes draw from.
        num_envs: parallel environments.
        workers: processes (0: in this process).
        seed: seeds every env's stream of episode seeds and shape draws.
        weights: probability of each shape per episode (default: uniform).
        max_steps: control steps per training episode (``None``: the session's ``max_steps``).
        device: torch device of the returned tensors.
    """

    def __init__(self, task: dict, shapes: list[Shape], num_envs: int = 8, workers: int = 2, seed: int = 0,
                 weights: list[float] | None = None, max_steps: int | None = None, device: str = "cpu"):
        if not shapes:
            raise ValueError("TaskVecEnv needs at least one shape")
        w = np.ones(len(shapes)) if weights is None else np.asarray(weights, np.float64)
        if len(w) != len(shapes) or np.any(w < 0) or w.sum() <= 0:
            raise ValueError(f"weights must be {len(shapes)} non-negative numbers with a positive sum, got {weights}")
        w = w / w.sum()
        self.num_envs, self.device, self.cfg = int(num_envs), device, {"task": task.get("name")}
        self.workers = min(int(workers), self.num_envs)
        splits = np.array_split(np.arange(self.num_envs), max(1, self.workers))
        self._splits = [s.tolist() for s in splits if len(s)]
        target = str(task["session"].get("_target_"))
        if self.workers == 0:
            try:
                self._local = _EnvGroup(task, shapes, w, list(range(self.num_envs)), seed, max_steps)
            except Exception as exc:  # noqa: BLE001 - a session that cannot be built: one line
                raise build_error("task.session", target, "building it", exc) from None
            self._conns, self._procs = [], []
        else:
            self._local = None
            ctx = mp.get_context("spawn")
            self._conns, self._procs = [], []
            for ids in self._splits:
                parent, child = ctx.Pipe()
                proc = ctx.Process(target=_worker, args=(child, task, shapes, w, ids, seed, max_steps, 1), daemon=True)
                proc.start()
                child.close()
                self._conns.append(parent)
                self._procs.append(proc)
            for conn in self._conns:  # each worker built its sessions, or says why not
                kind, trace = conn.recv()
                if kind == "fatal":
                    self.close()
                    raise worker_error("task.session", target, trace, "a training worker")
        first = self._call("reset")
        sample = first[0]
        self.obs_spec = {k: tuple(np.asarray(v).shape) for k, v in sample.items()}
        self._obs = self._stack(first)
        self.max_episode_length = int(max_steps or 256)
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long, device=device)
        self.num_actions = int(session_class(task).num_actions)  # the session class's, its one place
        self.episodes: list[dict] = []  # every ended episode (success, length, shape, return)

    def _call(self, cmd: str, actions: np.ndarray | None = None):
        if self._local is not None:
            return self._local.reset() if cmd == "reset" else self._local.step(actions)
        for conn, ids in zip(self._conns, self._splits, strict=True):
            conn.send((cmd, None if actions is None else actions[ids]))
        replies = [conn.recv() for conn in self._conns]
        if cmd == "reset":
            return [o for r in replies for o in r]
        obs = [o for r in replies for o in r[0]]
        return (obs, np.concatenate([r[1] for r in replies]), np.concatenate([r[2] for r in replies]),
                np.concatenate([r[3] for r in replies]), [e for r in replies for e in r[4]])

    def _stack(self, obs: list[dict]) -> TensorDict:
        data = {k: torch.as_tensor(np.stack([o[k] for o in obs]), dtype=torch.float32, device=self.device)
                for k in obs[0]}
        return TensorDict(data, batch_size=[len(obs)], device=self.device)

    def get_observations(self) -> TensorDict:
        return self._obs

    def step(self, actions: torch.Tensor):
        acts = actions.detach().cpu().numpy().astype(np.float32)
        obs, rew, term, trunc, ended = self._call("step", acts)
        self._obs = self._stack(obs)
        dones = torch.as_tensor(term | trunc, device=self.device)
        self.episode_length_buf += 1
        self.episode_length_buf[dones] = 0
        extras = {"time_outs": torch.as_tensor(trunc, device=self.device)}
        if ended:
            self.episodes.extend(ended)
            extras["log"] = {"/success_rate": float(np.mean([e["success"] for e in ended])),
                             "/episode_steps": float(np.mean([e["length"] for e in ended]))}
        return (self._obs, torch.as_tensor(rew, device=self.device), dones.long(), extras)

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
        for conn in self._conns:
            with contextlib.suppress(OSError):
                conn.send(("close", None))
        for proc in self._procs:
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
