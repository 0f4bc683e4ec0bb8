"""``grt-serve`` (``python -m grt.serve policy=NAME serve.port=PORT``): serve a GRT policy over ``grt-policy/1``.

The policy runs here; a red-team run elsewhere reaches it with ``policy=remote policy.url=URL``. The first
line printed is that URL. A batched policy (insertion, drawer) is served for the task of the ``task``
group (``task=drawer policy=drawer_state``): its observation groups and action size go into the hello,
and a checkpoint trained for another task is refused here. A grasp planner (``task=grasp
policy=antipodal``) is served with its ``plan``. Ctrl-C stops the server (exit code 0); SIGTERM too, with
exit code 143 as every GRT app. A ``serve.port`` outside 0-65535 is one ``error:`` line, exit code 2.
"""

from __future__ import annotations

import hashlib
import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

import grt
from grt.cli._common import CONF_DIR, exit_on_user_error, run_cli
from grt.config import plain, validate
from grt.errors import TERMINATED, Terminated
from grt.policies.base import BatchedPolicy, GraspObservation, GraspPolicy, PolicyServerError
from grt.policy_server import PolicyServer
from grt.runfolder.lock import LOCK, discard_new
from grt.targets import build
from grt.tasks import session_class

log = logging.getLogger("grt.serve")


def make_server(cfg: DictConfig) -> PolicyServer:
    """The server of ``cfg.policy`` for ``cfg.task`` with the ``cfg.serve`` settings (listening, not serving yet).

    Raises:
        PolicyServerError: a policy GRT cannot serve, or one made for another task.
    """
    port = cfg.serve.port
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:  # -5: an OverflowError
        raise PolicyServerError(f"serve.port={port}: a port is a whole number from 1 to 65535 (0: any free one, "
                                "the first line printed says which)")
    task = plain(cfg.task)
    session = session_class(task)
    task_name = getattr(session, "task_name", "") or task["name"]
    policy = build(cfg.policy, "policy")
    if "torch" in sys.modules and cfg.serve.threads:
        sys.modules["torch"].set_num_threads(int(cfg.serve.threads))
    choice = HydraConfig.get().runtime.choices.get("policy", "policy") if HydraConfig.initialized() else "policy"
    common = dict(task=task_name, name=str(choice), version=_version(cfg.policy), host=str(cfg.serve.host),
                  port=int(cfg.serve.port), token=cfg.serve.token, max_message=int(cfg.serve.max_message))
    try:
        return _server(policy, session, task, task_name, str(choice), common)
    except OSError as err:  # the port is taken, or the host is not an interface of this machine
        raise PolicyServerError(f"cannot listen on {cfg.serve.host}:{cfg.serve.port} ({err.strerror or err}): "
                                "pick another serve.port (0: any free one) or serve.host") from None


def _server(policy, session, task: dict, task_name: str, choice: str, common: dict) -> PolicyServer:
    if isinstance(policy, GraspPolicy):
        if session.num_actions or session.observation_spec():
            raise PolicyServerError(f"policy={choice} is a grasp planner, task={task['name']} is a closed-loop "
                                    "task: serve it with task=grasp")

        def plan(points, viewpoints, table_z, seed, context):
            return policy.plan(GraspObservation(points, viewpoints, table_z, context), seed)

        return PolicyServer(plan=plan, kind="grasp", context_radius=float(getattr(policy, "context_radius", 0.0)
                                                                           or 0.0), **common)
    if not isinstance(policy, BatchedPolicy):
        raise PolicyServerError(f"policy={choice} ({type(policy).__name__}) is neither a batched policy nor a "
                                "grasp planner: GRT serves those two kinds")
    spec = session.observation_spec(**{k: v for k, v in task["session"].items() if k == "cloud_points"})
    check = getattr(policy, "check", None)
    if check is not None:  # a checkpoint for another task or observation size: refused here, naming both
        check(task_name, spec, session.num_actions)
    # the groups the policy reads (all the task's when it does not say): nothing else crosses the wire
    obs = getattr(policy, "input_spec", None) or getattr(policy, "obs_spec", None) or spec
    return PolicyServer(act=policy.act, reset=policy.reset, kind="batched", obs=obs,
                        action_size=session.num_actions, **common)


def _version(policy_cfg: DictConfig) -> str:
    """GRT's version, and the checkpoint's content hash when the policy has one (a new file: a new policy)."""
    ckpt = policy_cfg.get("checkpoint")
    if ckpt and Path(str(ckpt)).is_file():
        return f"{grt.__version__}+{hashlib.sha256(Path(str(ckpt)).read_bytes()).hexdigest()[:12]}"
    return grt.__version__


@hydra.main(config_path=CONF_DIR, config_name="serve", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """Hydra entry point: print the URL, then serve until Ctrl-C."""
    with exit_on_user_error():
        validate(cfg, classes=("policy", "task.session"))
        server = make_server(cfg)
    try:  # a Ctrl-C from here on (as soon as the URL is out) stops the server cleanly
        print(server.url, flush=True)
        info = server.info
        print(f"serving {info['name']} {info['version']} ({info['kind']} policy for task {info['task']!r}"
              + (f", observations {info['obs']}, {info['action_size']} actions" if info["kind"] == "batched" else "")
              + ("; token required" if server.token else "") + "); Ctrl-C stops", flush=True)
        server.serve_forever()
    except Terminated:  # a scheduler's or `kill`'s stop: exit code 143, as every GRT app
        print("terminated (SIGTERM)", file=sys.stderr, flush=True)
        raise SystemExit(TERMINATED) from None
    except KeyboardInterrupt:  # Ctrl-C: how a server is stopped by hand (exit code 0)
        print("stopped", flush=True)
    finally:
        server.shutdown()
        _discard_if_empty(Path(HydraConfig.get().runtime.output_dir))


def _discard_if_empty(folder: Path) -> None:
    """A server leaves no folder (one per start piled up under ``outputs/serve/``): its log is on the console
    (``conf/serve.yaml``); a folder with something in it (a log file the user configured) stays."""
    if folder.is_dir() and not any(p.name != LOCK for p in folder.iterdir()):
        discard_new(folder)


def cli() -> None:
    """``grt-serve``."""
    run_cli(main)
