"""PPO training with rsl-rl's ``OnPolicyRunner`` on a :class:`~grt.rl.vec_env.TaskVecEnv`, resumable.

:func:`train` (one :class:`TrainSpec`) runs the runner one iteration at a time so that it can (1) show a
progress bar, (2) write ``metrics.csv`` (one row per iteration: episode success rate, return, losses,
seconds), (3) save a checkpoint with the GRT config inside every ``save_interval`` iterations
(``last.pt``) and keep the best by training success rate (``best.pt``), (4) resume a killed run from
``last.pt``, and (5) stop early once a target success rate has held for ``patience`` iterations, or on
validation episodes (:class:`ValidationSpec`). The shipped policy file (:func:`export_policy`) drops the
optimizer state so it stays small.
"""

from __future__ import annotations

import copy
import csv
import json
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from rsl_rl.runners import OnPolicyRunner
from tqdm.auto import tqdm

from grt.errors import UserError
from grt.fileio import atomic_path
from grt.rl.vec_env import TaskVecEnv

log = logging.getLogger(__name__)
FIELDS = ["iteration", "steps", "success_rate", "episodes", "mean_return", "episode_steps", "value_loss",
          "surrogate_loss", "entropy", "action_std", "learning_rate", "iteration_s", "anchor_mse"]


def grt_config(task_name: str, env: TaskVecEnv, train_cfg: dict, task_cfg: dict, extra: dict | None = None) -> dict:
    """The ``grt`` entry stored in a checkpoint (see :mod:`grt.policies.rsl_rl`)."""
    return {"task": task_name, "obs_spec": {k: list(v) for k, v in env.obs_spec.items()},
            "num_actions": env.num_actions, "train_cfg": copy.deepcopy(train_cfg), "task_cfg": task_cfg,
            **(extra or {})}


def _runner_cfg(train_cfg: dict) -> dict:
    keys = ("num_steps_per_env", "obs_groups", "actor", "critic", "algorithm")
    cfg = {k: copy.deepcopy(train_cfg[k]) for k in keys}
    cfg.update(save_interval=10**9, check_for_nan=True)
    return cfg


@dataclass
class ValidationSpec:
    """Early stopping on held-out validation episodes (the paper's fine-tuning).

    Attributes:
        score: ``checkpoint path -> score`` on the validation episodes, called every ``interval``
            iterations (and before the first): the best is kept as ``val_best.pt``.
        interval: PPO iterations between validations.
        patience: validations without improvement before training stops.
        perfect: a score that stops training at once (``None``: a continuous score has no perfect
            value, e.g. a drawer opening).
        tie: a later checkpoint within this much of the best replaces ``val_best.pt`` (the validation
            cannot tell them apart: the more trained one is kept), though it does not count as a gain.
        restart: called once before training (fresh or resumed) with the checkpoint iterations whose
            validations the run kept (a resume drops the stopped attempt's later ones): ``score``'s own
            records of any other validation are to go; returns what went, for the one log line saying so.
    """

    score: Callable[[Path], float]
    interval: int = 10
    patience: int = 3
    perfect: float | None = 1.0
    tie: float | None = None
    restart: Callable[[list[int]], list[str]] | None = None


@dataclass
class TrainSpec:
    """One PPO training (or fine-tuning) run: what :func:`train` takes.

    Attributes:
        train_cfg: rsl-rl runner config (``num_steps_per_env``, ``obs_groups``, ``actor``, ``critic``,
            ``algorithm``; optional ``seed``, ``freeze_normalization``).
        out_dir: run folder (checkpoints, ``metrics.csv``); an existing ``last.pt`` there is resumed.
        task_name, task_cfg: stored in every checkpoint.
        iterations: PPO iterations in total (a resumed run continues up to this number).
        init_checkpoint: start from this policy's weights (fine-tuning), unless resuming.
        save_interval: iterations between ``last.pt`` saves.
        target_success: stop early when the success rate over the last ``patience`` iterations'
            episodes reaches it (``None``: never).
        extra: more entries for the ``grt`` config stored in checkpoints.
        expert: a policy to warm-start from by :func:`behavior_clone` (fresh runs only); ``bc`` its
            keyword arguments (``steps``, ``epochs``, ``noise``).
        validation: early stopping on validation episodes (``None``: off).
        anchor: a :class:`grt.rl.anchor.NominalAnchor`, stepped after each PPO iteration (its error is
            the ``anchor_mse`` column).
        on_iteration: called with each metrics row (e.g. a W&B logger).
    """

    train_cfg: dict
    out_dir: str | Path
    task_name: str
    task_cfg: dict
    iterations: int
    init_checkpoint: str | None = None
    save_interval: int = 10
    target_success: float | None = None
    patience: int = 20
    extra: dict | None = None
    expert: object | None = None
    bc: dict | None = None
    validation: ValidationSpec | None = None
    anchor: object | None = None
    on_iteration: Callable[[dict], None] | None = None

    @classmethod
    def from_config(cls, train: dict, out_dir: str | Path, task_name: str, task_cfg: dict, **more) -> TrainSpec:
        """The spec of a ``conf/train`` config (``iterations``, ``save_interval``, ``target_success``,
        ``patience``, the runner's keys); ``more`` sets the other fields."""
        return cls(train_cfg=train, out_dir=out_dir, task_name=task_name, task_cfg=task_cfg,
                   iterations=int(train["iterations"]), save_interval=int(train["save_interval"]),
                   target_success=train["target_success"], patience=int(train["patience"]), **more)


def train(env: TaskVecEnv, spec: TrainSpec) -> dict:
    """Train (or resume) a PPO policy on ``env``; returns ``{"iterations", "steps", "best_success",
    "wall_s", "stopped_early", "out_dir", "validation"}``."""
    out = Path(spec.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(int(spec.train_cfg.get("seed", 0)))
    runner = _make_runner(env, spec.train_cfg)
    cfg = grt_config(spec.task_name, env, spec.train_cfg, spec.task_cfg, spec.extra)
    start_it, best = _start(runner, env, spec, cfg, out)
    if spec.train_cfg.get("freeze_normalization"):
        # The actor was fitted (warm start, or the checkpoint fine-tuned) under these statistics: PPO's
        # rollouts would move them and with them every input of the fixed weights.
        runner.alg.get_policy().update_normalization = lambda obs: None
        runner.alg.critic.update_normalization = lambda obs: None
    return _Loop(runner, env, spec, cfg, out, start_it, best).run()


def _make_runner(env: TaskVecEnv, train_cfg: dict) -> OnPolicyRunner:
    """rsl-rl's runner on ``env``, its PPO update wrapped so that each iteration's losses are kept."""
    runner = OnPolicyRunner(env, _runner_cfg(train_cfg), log_dir=None, device="cpu")
    update = runner.alg.update

    def update_and_keep_losses() -> dict:
        runner._last_losses = update()
        return runner._last_losses

    runner.alg.update = update_and_keep_losses
    return runner


def _start(runner: OnPolicyRunner, env: TaskVecEnv, spec: TrainSpec, cfg: dict, out: Path) -> tuple[int, float]:
    """Load the starting weights: ``last.pt`` (resume), else the initial checkpoint, else a behaviour-
    cloning warm start (written to ``cfg`` and ``warm_start.json``); returns ``(first iteration, best)``."""
    if (out / "last.pt").exists():
        state = read_checkpoint(out / "last.pt")  # a damaged file: one line, before rsl-rl reads it
        runner.load(str(out / "last.pt"))
        log.info("resuming %s at iteration %d", out, int(state["iter"]) + 1)
        return int(state["iter"]) + 1, float(state["grt"].get("best_success", -1.0))
    if spec.init_checkpoint:
        runner.load(str(spec.init_checkpoint), load_cfg={"actor": True, "critic": True}, strict=True)
    elif spec.expert is not None:
        warm = behavior_clone(runner, env, spec.expert, seed=int(spec.train_cfg.get("seed", 0)), **(spec.bc or {}))
        log.info("behaviour-cloning warm start: %s", warm)
        cfg["warm_start"] = warm
        write_json(out / "warm_start.json", warm)
    return 0, -1.0


class _Loop:
    """The PPO iterations of :func:`train`: one ``runner.learn(1)`` each, then the bookkeeping (metrics
    row, progress bar, ``best.pt`` / ``last.pt``, validation, early stop)."""

    def __init__(self, runner: OnPolicyRunner, env: TaskVecEnv, spec: TrainSpec, cfg: dict, out: Path,
                 start_it: int, best: float):
        self.runner, self.env, self.spec, self.cfg, self.out = runner, env, spec, cfg, out
        self.start_it, self.best = start_it, best
        self.rows = _read_rows(out / "metrics.csv", start_it)
        self.recent: deque = deque(maxlen=max(1, spec.patience))
        self.steps_per_it = env.num_envs * int(spec.train_cfg["num_steps_per_env"])
        v = spec.validation
        self.val = _Validation(v.score if v else None, out, v.patience if v else 3, v.perfect if v else 1.0,
                               v.tie if v else None, start_it=start_it)
        self._drop_after_restart()

    def _drop_after_restart(self) -> None:
        """Bring the run folder back to iteration ``start_it`` (what an uninterrupted training had then): a
        killed attempt's metrics rows, validations, ``val_best.pt`` and ``best.pt`` from later iterations are
        dropped (the validations by :class:`_Validation`, the score's own records by its ``restart``), in one
        log line."""
        dropped, metrics = list(self.val.dropped), self.out / "metrics.csv"
        if self.spec.validation is not None and self.spec.validation.restart is not None:
            dropped += self.spec.validation.restart([int(h[0]) for h in self.val.history])
        later = len(_read_rows(metrics, 10**12)) - len(self.rows)
        if later > 0:
            _write_rows(metrics, self.rows)
            dropped.insert(0, f"{later} rows of metrics.csv")
        best = self.out / "best.pt"
        it = _checkpoint_iter(best)
        if it is not None and it >= self.start_it:
            success = torch.load(best, map_location="cpu", weights_only=False)["grt"].get("best_success")
            best.unlink()
            dropped.append(f"best.pt (iteration {it + 1}, training success {success:.3f}" + (
                ")" if self.start_it == 0 else f"; it had replaced the best before then, {self.best:.3f}: the "
                "next training success to beat that writes best.pt)"))
        if dropped:
            log.warning("%s: resuming at iteration %d, dropped what the stopped attempt did after it: %s", self.out,
                        self.start_it, "; ".join(dropped))

    def save(self, name: str, it: int) -> None:
        _save(self.runner, self.out / name, it, {**self.cfg, "best_success": self.best})

    def run(self) -> dict:
        spec, started, stopped_early = self.spec, time.perf_counter(), False
        if self.start_it >= spec.iterations:
            log.info("%s: already trained %d iterations, train.iterations=%d: nothing to train (a larger "
                     "train.iterations trains longer)", self.out, self.start_it, spec.iterations)
        bar = tqdm(total=spec.iterations, initial=self.start_it, desc="ppo", unit="it", dynamic_ncols=True)
        due = self.start_it - 1  # the policy before any update, or last.pt's when its validation is missing
        if (spec.validation is not None and (due == -1 or self.start_it % spec.validation.interval == 0)
                and all(h[0] != due for h in self.val.history)):  # (a run killed while validating)
            self.save("val_current.pt", due)
            stopped_early = self.val.check(due, self.out / "val_current.pt") and due >= 0
        try:
            for it in range(self.start_it, self.start_it if stopped_early else spec.iterations):
                if self.step(it, bar):
                    stopped_early = True
                    break
        finally:
            bar.close()
        final_it = self.rows[-1]["iteration"] if self.rows else self.start_it
        window = [e["success"] for eps in self.recent for e in eps]
        # best_success: the best success rate over train.patience iterations (best.pt's); None when no window
        # was full (fewer iterations than train.patience), never the -1 it starts from.
        return {"iterations": int(final_it) + 1, "steps": (int(final_it) + 1) * self.steps_per_it,
                "best_success": self.best if self.best >= 0 else None,
                "last_success": float(np.mean(window)) if window else None, "last_window": len(self.recent),
                "wall_s": time.perf_counter() - started, "stopped_early": stopped_early,
                "out_dir": str(self.out), "validation": self.val.history}

    def step(self, it: int, bar) -> bool:
        """One PPO iteration and its bookkeeping; True when training should stop early."""
        spec, runner, env = self.spec, self.runner, self.env
        before, t0 = len(env.episodes), time.perf_counter()
        runner.current_learning_iteration = it
        runner.learn(1)
        drift = spec.anchor.step(runner.alg.get_policy()) if spec.anchor is not None else float("nan")
        ended = env.episodes[before:]
        row = _row(it, self.steps_per_it, ended, runner, time.perf_counter() - t0)
        row["anchor_mse"] = drift
        self.rows.append(row)
        _write_rows(self.out / "metrics.csv", self.rows)
        self.recent.append(ended)
        window = [e["success"] for eps in self.recent for e in eps]
        rate = float(np.mean(window)) if window else 0.0
        bar.update(1)
        bar.set_postfix(success=f"{rate:.2f}", ret=f"{row['mean_return']:.1f}")
        if spec.on_iteration:
            spec.on_iteration(row)
        full = len(self.recent) == self.recent.maxlen
        if window and rate > self.best and full:
            self.best = rate
            self.save("best.pt", it)
        if (it + 1) % spec.save_interval == 0 or it + 1 == spec.iterations:
            self.save("last.pt", it)
        if spec.validation is not None and (it + 1) % spec.validation.interval == 0:
            self.save("val_current.pt", it)
            if self.val.check(it, self.out / "val_current.pt"):
                self.save("last.pt", it)
                return True
        if spec.target_success is not None and full and rate >= spec.target_success:
            self.save("last.pt", it)
            return True
        return False


class _Validation:
    """Early stopping on validation episodes: keeps ``val_best.pt``, counts validations without gain."""

    def __init__(self, validate, out: Path, patience: int, perfect: float | None = 1.0, tie: float | None = None,
                 start_it: int = 0):
        """Resumed at ``start_it``: the validations of ``validation.json`` from later iterations (all of them
        from 0, whose run validates the untrained policy again) are dropped, the best and the count without
        gain replayed from the rest, and ``val_best.pt`` kept only if it is the rest's best; ``dropped`` says
        what went."""
        self.validate, self.out, self.patience, self.perfect, self.tie = validate, out, int(patience), perfect, tie
        state = out / "validation.json"
        saved = json.loads(state.read_text()) if state.exists() else {}
        self.history: list = []
        self.best, self.stale, self.dropped, later, kept = -np.inf, 0, [], [], None
        for it, score in saved.get("history", []):
            if start_it > 0 and it < start_it:
                self.history.append([it, score])
                kept = it if self._judge(score) else kept  # the iteration val_best.pt was then
            else:
                later.append(f"iteration {it + 1}: {score:.3f}")
        if later:
            write_json(state, self._state())
            self.dropped.append(f"{len(later)} validation{'s' if len(later) > 1 else ''} ({', '.join(later)})")
        best_it = _checkpoint_iter(out / "val_best.pt")
        if best_it is not None and best_it != kept:
            (out / "val_best.pt").unlink()
            self.dropped.append(f"val_best.pt (iteration {best_it + 1}" + (
                ")" if kept is None else f"; it had replaced iteration {kept + 1}'s, best {self.best:.3f}: "
                "the next validation to beat that writes val_best.pt)"))

    def _judge(self, score: float) -> bool:
        """Count ``score`` in; True when its checkpoint becomes ``val_best.pt``."""
        if score > self.best + (self.tie or 0.0):
            self.best, self.stale = score, 0
            return True
        self.stale += 1
        if self.tie is not None and score >= self.best - self.tie:  # a tie: keep the more trained policy
            self.best = max(self.best, score)
            return True
        return False

    def _state(self) -> dict:
        return {"history": self.history, "stale": self.stale, "best": self.best}

    def check(self, it: int, checkpoint: Path) -> bool:
        """Validate ``checkpoint``; True when training should stop."""
        score = float(self.validate(checkpoint))
        self.history.append([it, score])
        if self._judge(score):
            checkpoint.replace(self.out / "val_best.pt")
        write_json(self.out / "validation.json", self._state())
        log.info("validation at iteration %d: %.3f (best %.3f)", it + 1, score, self.best)
        return (self.perfect is not None and self.best >= self.perfect) or self.stale >= self.patience


def behavior_clone(runner: OnPolicyRunner, env: TaskVecEnv, expert, steps: int, epochs: int = 50,
                   noise: float = 0.1, gamma: float = 0.99, lr: float = 1e-3, seed: int = 0) -> dict:
    """Warm-start the actor (and critic) on an expert's rollouts before PPO (as DAPG-style methods do).

    The expert acts in ``env`` for ``steps`` steps per env, its actions perturbed by Gaussian ``noise``
    so the data covers states off its path; the actor's mean is fitted to the expert's (unperturbed)
    actions and the critic to the discounted returns of the rollouts. PPO then trains from there.

    Returns:
        ``{"bc_samples", "bc_action_mse", "bc_value_mse", "bc_expert_success"}``.
    """
    gen = torch.Generator().manual_seed(seed)
    obs_list, act_list, rew_list, done_list = [], [], [], []
    before = len(env.episodes)
    obs = env.get_observations()
    for _ in range(steps):
        act = torch.as_tensor(expert.act({k: obs[k].numpy() for k in obs.keys()}),  # noqa: SIM118 - a TensorDict iterates rows
                              dtype=torch.float32)
        obs_list.append(obs.clone())
        act_list.append(act)
        noisy = (act + noise * torch.randn(act.shape, generator=gen)).clamp(-1.0, 1.0)
        obs, rew, dones, extras = env.step(noisy)
        rew_list.append(rew.float())
        done_list.append((dones > 0) & ~extras["time_outs"].bool())
    returns, running = [], torch.zeros(env.num_envs)
    for rew, done in zip(reversed(rew_list), reversed(done_list), strict=True):
        running = rew + gamma * running * (~done).float()
        returns.append(running)
    returns = torch.stack(returns[::-1]).reshape(-1, 1)
    data = torch.stack(obs_list).reshape(-1)  # TensorDict of steps x envs, flattened
    actions = torch.stack(act_list).reshape(-1, env.num_actions)
    actor, critic = runner.alg.get_policy(), runner.alg.critic
    actor.update_normalization(data)
    critic.update_normalization(data)
    params = [p for n, p in actor.named_parameters() if "std" not in n] + list(critic.parameters())
    optim = torch.optim.Adam(params, lr=lr)
    n, batch = len(actions), 256
    for _ in range(epochs):
        for idx in torch.randperm(n, generator=gen).split(batch):
            loss_a = ((actor(data[idx]) - actions[idx]) ** 2).mean()
            loss_v = ((critic(data[idx]) - returns[idx]) ** 2).mean()
            optim.zero_grad()
            (loss_a + 0.1 * loss_v).backward()
            optim.step()
    with torch.no_grad():
        mse_a = float(((actor(data) - actions) ** 2).mean())
        mse_v = float(((critic(data) - returns) ** 2).mean())
    ended = env.episodes[before:]
    return {"bc_samples": n, "bc_action_mse": mse_a, "bc_value_mse": mse_v,
            "bc_expert_success": float(np.mean([e["success"] for e in ended])) if ended else float("nan")}


def export_policy(checkpoint: str | Path, dest: str | Path, metrics: dict | None = None) -> Path:
    """Write a small policy file (actor, critic, normalizers, config; no optimizer state)."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    small = {k: v for k, v in state.items() if k not in ("optimizer_state_dict",)}
    if metrics:
        small["grt"] = {**small["grt"], "metrics": metrics}
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(dest) as tmp:
        torch.save(small, tmp)
    return dest


class TrainingFolderError(UserError):
    """A file of a training's folder that cannot be read (a damaged ``last.pt``)."""


def read_checkpoint(path: Path) -> dict:
    """A checkpoint of :func:`_save` (GRT's own file, so unpickled in full).

    Raises:
        TrainingFolderError: the file cannot be read (cut short, not a checkpoint): names it and the fix.
    """
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
        int(state["iter"])
        return state
    except Exception as exc:  # noqa: BLE001 - whatever torch or pickle says, the file is damaged
        why = (str(exc).strip().splitlines() or [""])[0][:200]
        raise TrainingFolderError(
            f"{path} cannot be read ({type(exc).__name__}: {why}): the checkpoint is damaged (cut short by a full "
            f"disk or an unfinished copy?); restore it, or remove it to train again from iteration 0") from None


def _checkpoint_iter(path: Path) -> int | None:
    """The iteration a checkpoint of :func:`_save` was saved at (``None``: no such file)."""
    return int(read_checkpoint(path)["iter"]) if path.exists() else None


def finished(out: Path, iterations: int) -> dict | None:
    """``train.json`` of the training in ``out`` when it has nothing left to train: it was written after its
    ``last.pt`` (of iteration ``iterations - 1`` or later); ``None`` otherwise. A damaged ``last.pt`` raises
    :class:`TrainingFolderError`."""
    record, last = out / "train.json", out / "last.pt"
    if not last.is_file():
        return None
    trained = _checkpoint_iter(last) + 1
    if trained < iterations or not record.is_file():
        return None
    result = json.loads(record.read_text())
    return result if result.get("iterations") == trained else None


def _save(runner: OnPolicyRunner, path: Path, it: int, cfg: dict) -> None:
    state = runner.alg.save()
    state.update(iter=it, infos=None, grt=cfg)
    with atomic_path(path) as tmp:  # a kill never leaves a half-written checkpoint
        torch.save(state, tmp)


def _row(it: int, steps_per_it: int, ended: list[dict], runner: OnPolicyRunner, seconds: float) -> dict:
    losses = getattr(runner, "_last_losses", {}) or {}
    std = runner.alg.get_policy().output_std
    return {"iteration": it, "steps": (it + 1) * steps_per_it,
            "success_rate": float(np.mean([e["success"] for e in ended])) if ended else float("nan"),
            "episodes": len(ended),
            "mean_return": float(np.mean([e["ret"] for e in ended])) if ended else float("nan"),
            "episode_steps": float(np.mean([e["length"] for e in ended])) if ended else float("nan"),
            "value_loss": losses.get("value", float("nan")), "surrogate_loss": losses.get("surrogate", float("nan")),
            "entropy": losses.get("entropy", float("nan")), "action_std": float(std.detach().mean()),
            "learning_rate": float(runner.alg.learning_rate), "iteration_s": seconds}


def _read_rows(path: Path, upto: int) -> list[dict]:
    if not path.exists():
        return []
    with path.open() as f:
        rows = [{k: (float(v) if k not in ("iteration", "episodes") else int(float(v))) for k, v in r.items()}
                for r in csv.DictReader(f)]
    return [r for r in rows if r["iteration"] < upto]


def _write_rows(path: Path, rows: list[dict]) -> None:
    with atomic_path(path) as tmp, tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore", restval="nan")  # rows of an older layout resume too
        w.writeheader()
        w.writerows(rows)


def plot_curve(metrics_csv: str | Path, dest: str | Path, title: str = "") -> None:
    """Training curve: episode success rate and mean return against environment steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = _read_rows(Path(metrics_csv), 10**12)
    if not rows:
        return
    steps = np.array([r["steps"] for r in rows])
    succ = np.array([r["success_rate"] for r in rows])
    ret = np.array([r["mean_return"] for r in rows])
    k = max(1, len(rows) // 50)
    smooth = np.convolve(np.nan_to_num(succ), np.ones(k) / k, mode="same")
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    ax[0].plot(steps, succ, ".", alpha=0.3, ms=3)
    ax[0].plot(steps, smooth, "-", lw=2)
    ax[0].set(xlabel="environment steps", ylabel="training episode success", ylim=(-0.02, 1.02))
    ax[1].plot(steps, ret, ".", alpha=0.4, ms=3)
    ax[1].set(xlabel="environment steps", ylabel="mean episode return")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(dest, dpi=110)
    plt.close(fig)


def write_json(path: str | Path, data: dict) -> None:
    Path(path).write_text(json.dumps(data, indent=1, default=str))
