"""The policy-free fidelity check: one episode's actions replayed open-loop on the stock actor and on the swap.

Outcomes (:mod:`grt.tasks.maniskill.calibrate`) say *that* a swapped actor changes a task; this says *where*.
An episode's actions are recorded once on the stock actor (the policy's own episode, an action file, or
GRT's scripted push, :mod:`grt.tasks.maniskill.probe`), then stepped open-loop from the same seed twice: on
the stock actor again (the **replay floor**: PhysX on the CPU is deterministic, so this is 0 unless the env
is not) and on the nominal swap. The swapped actor's pose is compared with the stock actor's at every
control step: the distance between their origins (mm) and the angle between their orientations (deg). The
swap keeps the stock actor's frame (:mod:`grt.tasks.maniskill.geometry`), so the two poses are comparable
as they are.

Open loop on purpose: with the same actions, the robot does the same thing until the actor pushes back
differently, so the first step where the poses part names the moment the copy stops behaving like the stock
actor (the grasp closing, the lift, a roll), with no policy needed to react to it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np

#: a pose divergence above these is "the copy parted from the stock actor" (the onset step)
ONSET_MM, ONSET_DEG = 1.0, 1.0
#: the stock actor moved sideways by this at the start (m): the divergence of a copy that is right to 0.1 mm
NUDGE_M = 1e-4


@dataclass
class Episode:
    """One recorded episode.

    Attributes:
        seed: the episode seed; resets: how many resets preceded the steps (an env-driving policy resets the
            env again itself after the session's reset).
        actions: ``(T, ...)`` the actions exactly as given to the env's ``step``.
        poses: ``(T + 1, 7)`` the actor's pose after the last reset and after each step (m, wxyz quaternion).
    """

    seed: int
    resets: int = 1
    actions: list[np.ndarray] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)


class ActionLog(gym.Wrapper):
    """The session's env with every action and the actor's pose after it recorded (a reset starts over).

    Args:
        env: the session's gymnasium env; pose: ``() -> (7,)`` the swapped actor's pose now.
    """

    def __init__(self, env, pose):
        super().__init__(env)
        self.pose = pose
        self.episode: Episode | None = None
        self.resets = 0

    def reset(self, **kwargs):
        out = self.env.reset(**kwargs)
        self.resets += 1
        seed = np.asarray(kwargs.get("seed") if kwargs.get("seed") is not None else 0).reshape(-1)[0]
        self.episode = Episode(int(seed), self.resets, [], [self.pose()])
        return out

    def step(self, action):
        out = self.env.step(action)
        self.episode.actions.append(np.array(action, copy=True))
        self.episode.poses.append(self.pose())
        return out


def actor_pose(session) -> np.ndarray:
    """``(7,)`` the swapped actor's pose in sub-scene 0 (m, wxyz)."""
    raw = session.swap.build_of(0).actor.pose.raw_pose
    raw = raw.detach().cpu().numpy() if hasattr(raw, "detach") else np.asarray(raw)
    return np.asarray(raw, np.float64).reshape(-1, 7)[0]


def record(session, seed: int, run=None) -> Episode:
    """Record one episode of the session's policy (``run=None``: ``session.run_trial(seed)``, whatever its kind),
    or of ``run(session, seed)`` (a script that resets and steps ``session.env`` itself)."""
    log = ActionLog(session.env, lambda: actor_pose(session))
    inner, session.env = session.env, log
    try:
        (run or (lambda s, k: s.run_trial(k)))(session, int(seed))
    finally:
        session.env = inner
    if log.episode is None:
        raise RuntimeError("the episode never reset the env")
    return log.episode


def replay(session, seed: int, actions: list[np.ndarray], resets: int = 1, nudge_m: float = 0.0) -> np.ndarray:
    """The actor's poses ``(T' + 1, 7)`` when ``actions`` are stepped open-loop from a freshly built scene reset
    with ``seed`` (``resets - 1`` plain resets more, as the recorded episode had; the actor then moved by
    ``nudge_m`` along x); ``T' < T`` when the simulation failed at step ``T' + 1`` (the poses up to it)."""
    session.reset(int(seed), rebuild=True)
    for _ in range(int(resets) - 1):
        session.env.reset(seed=int(seed))
    if nudge_m:
        _nudge(session, nudge_m)
    poses = [actor_pose(session)]
    for action in actions:
        try:
            session.env.step(action)
        except Exception:  # noqa: BLE001 - a physics failure ends the comparison where it happened
            break
        pose = actor_pose(session)
        if not np.isfinite(pose).all():
            break
        poses.append(pose)
    return np.asarray(poses)


def _nudge(session, dx: float) -> None:
    from mani_skill.utils.structs.pose import Pose

    actor = session.swap.build_of(0).actor
    raw = actor.pose.raw_pose.clone()
    raw[..., 0] += dx
    actor.set_pose(Pose.create(raw))


def divergence(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per step, the distance (mm) between two pose series' origins and the angle (deg) between their
    orientations, over their common length. ``a``, ``b``: ``(T, 7)`` (m, wxyz)."""
    n = min(len(a), len(b))
    a, b = np.asarray(a[:n], np.float64), np.asarray(b[:n], np.float64)
    mm = np.linalg.norm(a[:, :3] - b[:, :3], axis=1) * 1000.0
    qa = a[:, 3:] / np.linalg.norm(a[:, 3:], axis=1, keepdims=True)
    qb = b[:, 3:] / np.linalg.norm(b[:, 3:], axis=1, keepdims=True)
    dot = np.clip(np.abs(np.sum(qa * qb, axis=1)), 0.0, 1.0)
    return mm, np.degrees(2.0 * np.arccos(dot))


def summary(mm: np.ndarray, deg: np.ndarray) -> dict:
    """The figures of one divergence series: its largest and final values, the step of the largest, and the
    onset (the first step over :data:`ONSET_MM` or :data:`ONSET_DEG`, ``None`` if never)."""
    over = np.flatnonzero((mm > ONSET_MM) | (deg > ONSET_DEG))
    return {"max_mm": round(float(mm.max(initial=0.0)), 3), "max_deg": round(float(deg.max(initial=0.0)), 3),
            "final_mm": round(float(mm[-1]), 3) if len(mm) else 0.0,
            "final_deg": round(float(deg[-1]), 3) if len(deg) else 0.0,
            "max_step": int(np.argmax(mm)) if len(mm) else 0,
            "onset_step": int(over[0]) if len(over) else None}


def check(session, candidate: tuple, episode: Episode, source: str) -> dict:
    """Replay ``episode`` on the stock actor, on the stock actor nudged by :data:`NUDGE_M`, and on ``candidate``
    (``(mesh, parts)``, GRT's frame, as :meth:`~grt.tasks.maniskill.session.ManiSkillSession.load_object` takes
    them), and compare the poses with the stock replay's.

    Two floors read the swap's figures: ``replay`` (the stock replay against the recorded episode, or against a
    second replay for actions read from a file: 0 when the env is deterministic, as PhysX on the CPU is) and ``nudge`` (how far the episode carries a 0.1 mm error of
    the start: what any copy, however faithful, would show; a chaotic episode, a rolling ball, has a large one).

    Returns:
        ``{"source", "seed", "steps", "swap_steps", "replay": summary, "nudge": summary, "swap": summary,
        "series": {name_mm, name_deg for swap, nudge, replay; "stock_z_m"}}``; ``swap_steps`` < ``steps`` when the
        swap's simulation failed.
    """
    session.load_object(None, None)
    stock = replay(session, episode.seed, episode.actions, episode.resets)
    recorded = np.asarray(episode.poses) if episode.poses else replay(session, episode.seed, episode.actions,
                                                                       episode.resets)  # a file: replay it twice
    nudged = replay(session, episode.seed, episode.actions, episode.resets, NUDGE_M)
    session.load_object(*candidate)
    swap = replay(session, episode.seed, episode.actions, episode.resets)
    out = {"source": source, "seed": int(episode.seed), "steps": len(episode.actions), "swap_steps": len(swap) - 1}
    series = {"stock_z_m": stock[:, 2].round(5).tolist()}
    for name, other in (("replay", recorded), ("nudge", nudged), ("swap", swap)):
        mm, deg = divergence(stock, other)
        out[name] = summary(mm, deg)
        series[f"{name}_mm"], series[f"{name}_deg"] = mm.round(3).tolist(), deg.round(3).tolist()
    return {**out, "series": series}
