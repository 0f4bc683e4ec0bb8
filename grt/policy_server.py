"""GRT's policy protocol ``grt-policy/1``: serve a policy from its own process, virtualenv or machine.

This module needs **numpy, websockets and msgpack only** (no simulator, no torch, no other GRT module):
copy this one file into the policy's own environment (or install GRT there with ``--no-deps``), and
wrap your policy's ``act`` function::

    import numpy as np
    from policy_server import PolicyServer        # (grt.policy_server where GRT is installed)

    def act(obs):                                 # obs: {"state": (N, 24) float32}
        return np.zeros((len(obs["state"]), 6), np.float32)     # (N, 6) in [-1, 1]

    PolicyServer(act=act, kind="batched", task="insertion", obs={"state": [24]}, action_size=6,
                 name="my-policy", version="1", port=8000).serve_forever()

GRT then red-teams it with ``policy=remote policy.url=ws://127.0.0.1:8000`` (docs/remote-policies.md).

Transport: one WebSocket connection per evaluator worker; every message is one binary frame of msgpack,
numpy arrays as msgpack extension type 1 holding ``[dtype, shape, raw bytes]`` (numeric dtypes only:
never pickle, never code from the peer). Messages, all maps with a ``type``:

- client ``hello {protocol, token?}`` -> server ``hello {protocol, kind, task, name, version, ...}``:
  ``kind: batched`` adds ``obs: {group: shape}`` and ``action_size``; ``kind: grasp`` adds
  ``context_radius``. A wrong protocol or token gets ``error {message}`` and the connection is closed.
- ``reset {id, seed}`` -> ``ok {id}``; ``act {id, obs: {group: (N, ...)}}`` -> ``action {id, action: (N, A)}``.
- ``plan {id, seed, points (P,3), viewpoints (P,3), table_z, context (Q,3)|nil}`` ->
  ``grasps {id, grasps: [{pose (4,4), width, score, info}]}`` (best first; empty: no grasp found).
- any request -> ``error {id, message}`` when the policy raised or the request was malformed.
"""

from __future__ import annotations

import hmac
import inspect
import threading
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect as ws_connect
from websockets.sync.server import serve as ws_serve

# websockets 17.1 deprecated a connection opened outside a `with` block unless `legacy=True` says so (a test
# fails on that warning); 15-17.0 have no such flag. The client keeps one connection open across calls.
_LEGACY = {"legacy": True} if "legacy" in inspect.signature(ws_connect).parameters else {}

PROTOCOL = "grt-policy/1"
#: Largest message either side accepts (bytes): a 20,000-point cloud with viewpoints is ~0.5 MB.
MAX_MESSAGE = 16 * 2**20
_ARRAY_EXT = 1
_DTYPE_KINDS = "biuf"  # bool, signed, unsigned, float: no objects, strings or structured records
KINDS = ("batched", "grasp")


class ProtocolError(RuntimeError):
    """A message that does not follow ``grt-policy/1`` (undecodable, wrong type, bad array)."""


# ------------------------------------------------------------------------------------------ encoding
def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in _DTYPE_KINDS:
            raise ProtocolError(f"cannot send an array of dtype {obj.dtype} (numeric arrays only)")
        arr = np.ascontiguousarray(obj)
        return msgpack.ExtType(_ARRAY_EXT, msgpack.packb([arr.dtype.str, list(arr.shape), arr.tobytes()]))
    if isinstance(obj, np.generic):
        return obj.item()
    raise ProtocolError(f"cannot send a {type(obj).__name__} (maps, lists, numbers, strings, numpy arrays only)")


def _ext_hook(code: int, data: bytes) -> np.ndarray:
    if code != _ARRAY_EXT:
        raise ProtocolError(f"unknown msgpack extension type {code}")
    dtype_str, shape, raw = msgpack.unpackb(data)
    dtype = np.dtype(dtype_str)
    if dtype.kind not in _DTYPE_KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise ProtocolError(f"refused array dtype {dtype_str!r} (numeric arrays only)")
    shape = tuple(int(s) for s in shape)
    if any(s < 0 for s in shape) or int(np.prod(shape)) * dtype.itemsize != len(raw):
        raise ProtocolError(f"array of shape {shape} and dtype {dtype_str} does not match its {len(raw)} bytes")
    return np.frombuffer(raw, dtype=dtype).reshape(shape).copy()  # writable, owns its memory


def pack(message: dict) -> bytes:
    """One protocol message as msgpack bytes (numpy arrays as extension type 1)."""
    return msgpack.packb(message, default=_default, use_bin_type=True)


def unpack(data: bytes | str) -> dict:
    """The message in ``data``; raises :class:`ProtocolError` for anything but a msgpack map with a type."""
    if not isinstance(data, bytes | bytearray):
        raise ProtocolError("text frame received: grt-policy/1 sends binary msgpack frames")
    try:
        message = msgpack.unpackb(data, ext_hook=_ext_hook, raw=False)
    except ProtocolError:
        raise
    except Exception as err:
        raise ProtocolError(f"undecodable message ({type(err).__name__}: {err})") from None
    if not isinstance(message, dict) or not isinstance(message.get("type"), str):
        raise ProtocolError("a message must be a map with a 'type'")
    return message


# ------------------------------------------------------------------------------------------ server
class PolicyServer:
    """Serve ``act`` (and ``reset``) of a batched policy, or ``plan`` of a grasp planner, over ``grt-policy/1``.

    Args:
        act: ``act({group: (N, ...)}) -> (N, A)`` actions in [-1, 1] (``kind="batched"``).
        reset: ``reset(seed)`` at the start of each episode (optional).
        plan: ``plan(points, viewpoints, table_z, seed, context) -> [{"pose": (4,4), "width": m,
            "score": float, "info": {...}}]`` best first (``kind="grasp"``).
        kind: ``"batched"`` or ``"grasp"``.
        task: the GRT task the policy is for (``insertion``, ``drawer``, ``grasp``); checked by the client.
        obs: observation groups and their shapes without the batch axis (``batched``).
        action_size: ``A`` (``batched``).
        context_radius: meters of table top around the object the planner wants (``grasp``; 0: none).
        name, version: what the policy is (recorded by the client).
        host: interface to bind: ``127.0.0.1`` (this machine only) unless you mean to expose it.
        port: TCP port (0: any free one; :attr:`url` says which).
        token: a shared secret the client must send in its hello (``None``: none asked).
        max_message: largest message accepted (bytes).

    Calls into the policy are serialized (one at a time, whatever the number of connections), so the
    policy needs not be thread-safe.
    """

    def __init__(self, *, act: Callable | None = None, reset: Callable | None = None,
                 plan: Callable | None = None, kind: str = "batched", task: str, obs: dict | None = None,
                 action_size: int | None = None, context_radius: float = 0.0, name: str = "policy",
                 version: str = "0", host: str = "127.0.0.1", port: int = 8000, token: str | None = None,
                 max_message: int = MAX_MESSAGE):
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
        info: dict[str, Any] = {"protocol": PROTOCOL, "kind": kind, "task": str(task), "name": str(name),
                                "version": str(version)}
        if kind == "batched":
            if act is None or obs is None or action_size is None:
                raise ValueError("kind='batched' needs act, obs ({group: shape}) and action_size")
            info.update(obs={str(k): [int(s) for s in v] for k, v in obs.items()}, action_size=int(action_size))
        elif plan is None:
            raise ValueError("kind='grasp' needs plan")
        else:
            info["context_radius"] = float(context_radius)
        self.info, self._act, self._reset, self._plan = info, act, reset, plan
        self.token = token or None
        self._lock, self._serving = threading.Lock(), threading.Event()
        self._server = ws_serve(self._handle, host, int(port), max_size=int(max_message), compression=None)
        self.host, self.port = host, int(self._server.socket.getsockname()[1])

    @property
    def url(self) -> str:
        """What the client's ``policy.url`` takes."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def serve_forever(self) -> None:
        """Answer requests until :meth:`shutdown` (or Ctrl-C)."""
        self._serving.set()
        self._server.serve_forever()

    def shutdown(self) -> None:
        """Stop answering and close the port; returns at once when :meth:`serve_forever` never ran (a Ctrl-C
        between the URL's line and the loop: websockets' own shutdown would wait for the loop forever)."""
        if self._serving.is_set():
            self._server.shutdown()
        else:
            self._server.socket.close()

    def __enter__(self) -> PolicyServer:
        threading.Thread(target=self.serve_forever, daemon=True).start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    # --------------------------------------------------------------------------------- protocol
    def _handle(self, conn) -> None:
        try:
            refused = self._greet(conn)
            if refused is not None:
                conn.send(pack({"type": "error", "message": refused}))
                conn.close(1008, refused[:120])
                return
            conn.send(pack({"type": "hello", **self.info}))
            for data in conn:
                conn.send(self._answer(data))
        except ConnectionClosed:
            pass

    def _greet(self, conn) -> str | None:
        """Why the client is refused (wrong protocol or token), or ``None``."""
        try:
            hello = unpack(conn.recv(timeout=10.0))
        except (TimeoutError, ProtocolError) as err:
            return f"no valid hello ({err})"
        if hello.get("type") != "hello" or hello.get("protocol") != PROTOCOL:
            return f"protocol mismatch: the server speaks {PROTOCOL}, the client {hello.get('protocol')!r}"
        if self.token is not None and not hmac.compare_digest(str(hello.get("token") or ""), self.token):
            return "bad or missing token: give the server's token (policy.token)"
        return None

    def _answer(self, data) -> bytes:
        """The packed reply to one request; the policy's own failure (or an unsendable answer) is an
        ``error`` reply for the client to record, never a crash of the server."""
        rid = None
        try:
            msg = unpack(data)
            rid = msg.get("id")
            return pack(self._reply(msg))
        except Exception as err:
            return pack({"type": "error", "id": rid, "message": f"{type(err).__name__}: {err}"})

    def _reply(self, msg: dict) -> dict:
        rid, kind = msg.get("id"), msg["type"]
        with self._lock:
            if kind == "reset":
                if self._reset is not None:
                    self._reset(int(msg["seed"]))
                return {"type": "ok", "id": rid}
            if kind == "act" and self._act is not None:
                obs = msg["obs"]
                if not isinstance(obs, dict) or not all(isinstance(v, np.ndarray) for v in obs.values()):
                    raise ProtocolError("act: obs must be a map of arrays")
                return {"type": "action", "id": rid, "action": np.asarray(self._act(obs))}
            if kind == "plan" and self._plan is not None:
                grasps = self._plan(msg["points"], msg["viewpoints"], float(msg["table_z"]), int(msg["seed"]),
                                    msg.get("context"))
                return {"type": "grasps", "id": rid, "grasps": [_grasp_message(g) for g in grasps]}
        raise ProtocolError(f"a {self.info['kind']} server does not answer {kind!r}")


def _grasp_message(grasp: Any) -> dict:
    """``{pose, width, score, info}`` of a grasp given as a dict or an object with those attributes."""
    get = grasp.get if isinstance(grasp, dict) else (lambda k, d=None: getattr(grasp, k, d))
    info = {str(k): v for k, v in (get("info") or {}).items()
            if isinstance(v, int | float | str | bool | np.ndarray | np.generic)}
    return {"pose": np.asarray(get("pose"), np.float64), "width": float(get("width")),
            "score": float(get("score")), "info": info}


# ------------------------------------------------------------------------------------------ client
class PolicyClient:
    """One connection to a policy server: the hello, then requests answered in order.

    Args:
        url: ``ws://host:port``.
        token: the server's shared secret, if it asks for one.
        timeout: seconds to wait for a reply.
        open_timeout: seconds to wait for the connection and the hello.
        max_message: largest message accepted (bytes).

    Raises (from :meth:`connect`): ``OSError`` (nothing listens there), :class:`ProtocolError`
    (the server refused the hello, or is no ``grt-policy/1`` server).
    """

    def __init__(self, url: str, token: str | None = None, timeout: float = 30.0, open_timeout: float = 10.0,
                 max_message: int = MAX_MESSAGE):
        self.url, self.token, self.timeout = url, token, float(timeout)
        self.open_timeout, self.max_message = float(open_timeout), int(max_message)
        self.conn = None
        self.server: dict = {}
        self._next_id = 0

    def connect(self) -> dict:
        """Open the connection and exchange hellos; returns the server's hello."""
        self.conn = ws_connect(self.url, open_timeout=self.open_timeout, max_size=self.max_message,
                               compression=None, proxy=None, **_LEGACY)
        try:
            self.conn.send(pack({"type": "hello", "protocol": PROTOCOL, "token": self.token}))
            reply = unpack(self.conn.recv(timeout=self.open_timeout))
        except ConnectionClosed as err:
            self.close()
            raise ProtocolError(f"the server closed the connection during the hello ({err})") from None
        except (TimeoutError, ProtocolError) as err:
            self.close()
            raise ProtocolError(f"no valid hello from the server ({err}): is it a {PROTOCOL} server?") from None
        if reply["type"] == "error":
            self.close()
            raise ProtocolError(str(reply.get("message")))
        if reply["type"] != "hello" or reply.get("protocol") != PROTOCOL:
            self.close()
            raise ProtocolError(f"protocol mismatch: the client speaks {PROTOCOL}, the server "
                                f"{reply.get('protocol')!r}")
        self.server = reply
        return reply

    def request(self, message: dict) -> dict:
        """Send ``message`` and return its reply (replies to earlier, timed-out requests are skipped).

        Raises:
            TimeoutError: no reply within :attr:`timeout`.
            websockets.exceptions.ConnectionClosed, OSError: the connection broke.
            ProtocolError: an undecodable reply.
        """
        import time

        self._next_id += 1
        rid = self._next_id
        self.conn.send(pack({**message, "id": rid}))
        deadline = time.monotonic() + self.timeout
        while True:
            reply = unpack(self.conn.recv(timeout=max(deadline - time.monotonic(), 0.0)))
            if reply.get("id") == rid or (reply.get("id") is None and reply["type"] == "error"):
                return reply  # (an error without id: the server could not read our request)
            if not isinstance(reply.get("id"), int) or reply["id"] > rid:
                raise ProtocolError(f"reply to an unknown request {reply.get('id')!r}")

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
            self.conn = None
