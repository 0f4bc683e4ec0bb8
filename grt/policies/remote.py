"""Policies that live elsewhere: clients of a ``grt-policy/1`` server (:mod:`grt.policy_server`).

``policy=remote policy.url=ws://HOST:PORT`` red-teams a policy served from its own process, virtualenv
or machine (``python -m grt.serve policy=...``, or a user's own ``act`` function wrapped in
:class:`grt.policy_server.PolicyServer`). :func:`connect` says hello to the server once, and returns the
client of the kind it serves: :class:`RemoteBatchedPolicy` (closed-loop tasks) or
:class:`RemoteGraspPolicy` (the grasp task). Each evaluator worker then opens its own connection.

Failures, none of them silent:

- nothing listens at the URL, the server refuses the token or speaks another protocol, or it serves
  another task or other observations: :class:`PolicyServerError` (one line naming both sides, exit
  code 2), before any simulation;
- a reply that is malformed (wrong shape, non-finite action) or is the server's error:
  :class:`PolicyReplyError`, which the task records as a ``sim_error`` trial with the reason;
- the connection breaks in a trial, or a reply does not come within ``timeout`` s (a stalled server: no
  trial's fault, so never a ``sim_error``; the connection is dropped, so a late reply answers nothing):
  :class:`~grt.policies.base.PolicyInterrupted`; the worker re-runs the trial (up to three times), which
  reconnects (``retries`` attempts, waits doubling from ``retry_wait`` s) to a server that must be the same
  policy; if it stays down or silent: :class:`~grt.policies.base.PolicyUnavailable`, and the evaluation
  stops with one line (``resume=DIR`` finishes a red-team run later, every trial scored).
"""

from __future__ import annotations

import logging
import time

import numpy as np
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from grt.policies.base import (
    BatchedPolicy,
    Grasp,
    GraspObservation,
    GraspPolicy,
    PolicyInterrupted,
    PolicyServerError,
    PolicyUnavailable,
    observation_groups,
)
from grt.policy_server import MAX_MESSAGE, PolicyClient, ProtocolError

log = logging.getLogger(__name__)

_IDENTITY = ("kind", "task", "name", "version", "obs", "action_size", "context_radius")
_CONNECT_ERRORS = (OSError, ProtocolError, ConnectionClosed, InvalidHandshake, TimeoutError)


class PolicyReplyError(RuntimeError):
    """A reply that timed out, is malformed, or reports the policy's own error: the trial is a ``sim_error``."""


def describe(server: dict) -> str:
    """``name version (kind policy for task)`` of a server's hello."""
    return f"{server.get('name')} {server.get('version')} ({server.get('kind')} policy for {server.get('task')!r})"


class _Remote:
    """The connection logic both kinds share: hello once at construction, then lazily per process."""

    kind = ""

    def __init__(self, url: str, timeout: float = 30.0, token: str | None = None, retries: int = 3,
                 retry_wait: float = 1.0, open_timeout: float = 10.0, max_message: int = MAX_MESSAGE,
                 server: dict | None = None):
        self.url, self.timeout, self.token = str(url), float(timeout), token or None
        self.retries, self.retry_wait = int(retries), float(retry_wait)
        self.open_timeout, self.max_message = float(open_timeout), int(max_message)
        self.client: PolicyClient | None = None
        self.server = server if server is not None else hello(url, token, open_timeout, max_message)
        if self.server.get("kind") != self.kind:
            raise PolicyServerError(f"policy server {self.url} serves a {self.server.get('kind')!r} policy, "
                                    f"this client is for {self.kind!r}")

    @property
    def name(self) -> str:
        return describe(self.server)

    def _client(self) -> PolicyClient:
        """The open connection, reconnecting (bounded) when there is none.

        Raises:
            PolicyUnavailable: the server stays down, or came back as another policy.
        """
        if self.client is not None:
            return self.client
        waits = [self.retry_wait * 2 ** k for k in range(self.retries)]
        for attempt in range(self.retries + 1):
            client = PolicyClient(self.url, self.token, self.timeout, self.open_timeout, self.max_message)
            try:
                server = client.connect()
                break
            except _CONNECT_ERRORS as err:
                last = err
                if attempt < self.retries:
                    time.sleep(waits[attempt])
        else:
            raise PolicyUnavailable(f"policy server {self.url} is down: {self.retries + 1} connection attempts "
                                    f"over {sum(waits):g} s failed ({type(last).__name__}: {last})")
        if _identity(server) != _identity(self.server):
            client.close()
            raise PolicyUnavailable(f"policy server {self.url} came back as {describe(server)}, not "
                                    f"{describe(self.server)}")
        self.client = client
        return client

    def call(self, message: dict) -> dict:
        """The server's reply to ``message``.

        Raises:
            PolicyReplyError: an undecodable reply, or the server's error.
            PolicyInterrupted: the connection broke, or no reply came within ``timeout`` (the trial is re-run).
            PolicyUnavailable: the server stays down.
        """
        client = self._client()
        try:
            reply = client.request(message)
        except TimeoutError:  # the server stalled: no outcome of the trial's, which is re-run on a new connection
            self.close()
            raise PolicyInterrupted(f"no reply from {self.url} within {self.timeout:g} s (policy.timeout; a policy "
                                    "that is this slow needs a larger one)") from None
        except ProtocolError as err:
            raise PolicyReplyError(f"malformed reply from {self.url}: {err}") from None
        except (ConnectionClosed, OSError) as err:
            self.close()
            raise PolicyInterrupted(f"connection to policy server {self.url} lost ({err})") from None
        if reply["type"] == "error":
            raise PolicyReplyError(f"policy server {self.url} answered with an error: {reply.get('message')}")
        return reply

    def _check_task(self, task: str) -> None:
        if task != self.server.get("task"):
            raise PolicyServerError(f"policy server {self.url} serves {self.name}, but the run's task is "
                                    f"{task!r}: serve a policy for {task!r}")

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None

    def __getstate__(self) -> dict:  # a copy (to another process) opens its own connection
        return {**self.__dict__, "client": None}


def hello(url: str, token: str | None = None, open_timeout: float = 10.0, max_message: int = MAX_MESSAGE) -> dict:
    """The hello of the server at ``url`` (connect, exchange hellos, disconnect).

    Raises:
        PolicyServerError: nothing listens there, or the server refused us (token, protocol).
    """
    client = PolicyClient(url, token, open_timeout, open_timeout, max_message)
    try:
        server = client.connect()
    except (InvalidURI, ValueError) as err:
        raise PolicyServerError(f"policy.url={url!r} is not a WebSocket URL ({err}): give ws://HOST:PORT") from None
    except ProtocolError as err:
        raise PolicyServerError(f"policy server {url} refused the connection: {err}") from None
    except (OSError, InvalidHandshake, ConnectionClosed, TimeoutError) as err:
        raise PolicyServerError(f"no policy server at {url} ({type(err).__name__}: {err}); start one "
                                "(python -m grt.serve policy=NAME serve.port=PORT) or fix policy.url") from None
    finally:
        client.close()
    log.info("policy server %s: %s", url, describe(server))
    return server


def _identity(server: dict) -> tuple:
    return tuple(repr(server.get(k)) for k in _IDENTITY)


class RemoteBatchedPolicy(_Remote, BatchedPolicy):
    """A closed-loop batched policy (insertion, drawer) served elsewhere.

    Args: see :func:`connect`.
    """

    kind = "batched"

    def __init__(self, url: str, **kwargs):
        super().__init__(url, **kwargs)
        self.obs_spec = {k: tuple(v) for k, v in self.server["obs"].items()}
        self.num_actions = int(self.server["action_size"])

    def check(self, task: str, obs_spec: dict, num_actions: int) -> None:
        """Refuse a task whose name, observation groups or action size differ from the server's.

        Raises:
            PolicyServerError: naming both sides.
        """
        self._check_task(task)
        for group, want in sorted(self.obs_spec.items()):
            have = tuple(obs_spec[group]) if group in obs_spec else None
            if have is None:
                groups = observation_groups(obs_spec)
                raise PolicyServerError(f"policy server {self.url} ({self.name}) reads observation {group!r} of "
                                        f"shape {want}, which the task does not give (it gives {groups})")
            if have != want:
                raise PolicyServerError(f"policy server {self.url} ({self.name}) expects observation {group!r} of "
                                        f"shape {want}, the task gives {have}")
        if int(num_actions) != self.num_actions:
            raise PolicyServerError(f"policy server {self.url} ({self.name}) outputs {self.num_actions} actions, "
                                    f"the task takes {num_actions}")

    def reset(self, seed: int) -> None:
        self.call({"type": "reset", "seed": int(seed)})

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        sent = {k: np.asarray(v) for k, v in obs.items() if k in self.obs_spec}
        batch = len(next(iter(sent.values())))
        action = self.call({"type": "act", "obs": sent}).get("action")
        if not isinstance(action, np.ndarray) or action.shape != (batch, self.num_actions):
            shape = action.shape if isinstance(action, np.ndarray) else type(action).__name__
            raise PolicyReplyError(f"malformed reply from {self.url}: action of shape {shape}, expected "
                                   f"{(batch, self.num_actions)}")
        if not np.all(np.isfinite(action)):
            raise PolicyReplyError(f"malformed reply from {self.url}: non-finite action {action.tolist()}")
        return np.clip(action.astype(np.float32), -1.0, 1.0)


class RemoteGraspPolicy(_Remote, GraspPolicy):
    """A grasp planner (the grasp task) served elsewhere: the fused cloud in, ranked grasps out.

    Args: see :func:`connect`.
    """

    kind = "grasp"

    @property
    def context_radius(self) -> float:
        """Meters of table top around the object the planner wants (read by the grasp task)."""
        return float(self.server.get("context_radius") or 0.0)

    def check(self, task: str, obs_spec: dict, num_actions: int) -> None:
        """Refuse a task other than the server's (naming both)."""
        self._check_task(task)

    def plan(self, obs: GraspObservation, seed: int) -> list[Grasp]:
        reply = self.call({"type": "plan", "seed": int(seed), "points": np.asarray(obs.points),
                           "viewpoints": np.asarray(obs.viewpoints), "table_z": float(obs.table_z),
                           "context": None if obs.context is None else np.asarray(obs.context)})
        grasps = reply.get("grasps")
        if not isinstance(grasps, list):
            raise PolicyReplyError(f"malformed reply from {self.url}: grasps is a {type(grasps).__name__}")
        return [self._grasp(g, i) for i, g in enumerate(grasps)]

    def _grasp(self, g, i: int) -> Grasp:
        try:
            pose = np.asarray(g["pose"], np.float64)
            width, score = float(g["width"]), float(g["score"])
            ok = pose.shape == (4, 4) and np.all(np.isfinite(pose)) and np.isfinite(width)
        except (TypeError, KeyError, ValueError) as err:
            raise PolicyReplyError(f"malformed reply from {self.url}: grasp {i} ({err})") from None
        if not ok:
            raise PolicyReplyError(f"malformed reply from {self.url}: grasp {i} needs a finite (4, 4) pose "
                                   "and width")
        return Grasp(pose=pose, width=width, score=score, info=dict(g.get("info") or {}))


def connect(url: str, timeout: float = 30.0, token: str | None = None, retries: int = 3, retry_wait: float = 1.0,
            open_timeout: float = 10.0, max_message: int = MAX_MESSAGE) -> RemoteBatchedPolicy | RemoteGraspPolicy:
    """The client of the policy served at ``url``, of the kind the server states in its hello.

    Args:
        url: ``ws://HOST:PORT`` (what ``python -m grt.serve`` prints on its first line).
        timeout: seconds a reply may take (> 0); without one the trial is re-run, and the evaluation stops
            when it stays silent (see the module docstring).
        token: the server's shared secret (``serve.token``), if it asks for one.
        retries: reconnection attempts after the connection broke, waits doubling from ``retry_wait`` s.
        open_timeout: seconds to connect and exchange hellos.
        max_message: largest message accepted (bytes).

    Raises:
        PolicyServerError: no server there, refused, or a server of an unknown kind.
    """
    for key, value in (("timeout", timeout), ("open_timeout", open_timeout)):
        if not float(value) > 0:  # 0: every request "timed out" at once, every trial lost
            raise PolicyServerError(f"policy.{key}={value}: the seconds to wait for the policy server must be > 0 "
                                    f"(the default: policy.{key}={30.0 if key == 'timeout' else 10.0})")
    server = hello(url, token, open_timeout, max_message)
    kinds = {"batched": RemoteBatchedPolicy, "grasp": RemoteGraspPolicy}
    if server.get("kind") not in kinds:
        raise PolicyServerError(f"policy server {url} serves a {server.get('kind')!r} policy; GRT knows "
                                f"{sorted(kinds)}")
    return kinds[server["kind"]](url, timeout=timeout, token=token, retries=retries, retry_wait=retry_wait,
                                 open_timeout=open_timeout, max_message=max_message, server=server)
