"""Fixtures of the selector tests: small meshes and a local chat-completions server."""

from __future__ import annotations

import json
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest
import trimesh

API_KEY = "sk-test-SECRET-0123456789abcdef"


class ChatServer:
    """A threaded HTTP server on 127.0.0.1 speaking the OpenAI chat-completions protocol.

    ``replies`` is a list of assistant texts served in order (the last one repeats), or a callable
    ``(request_json) -> str``; a ``(status, content_type, body_bytes)`` reply is sent as it is
    instead of a chat completion (an error body, HTML, garbage). Every request body and its
    headers are kept in ``requests``.
    """

    def __init__(self, replies):
        self.replies = replies
        self.requests: list[dict] = []
        self.headers: list[dict] = []
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):  # noqa: N802 (http.server's naming)
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                server.requests.append(body)
                server.headers.append({k.lower(): v for k, v in self.headers.items()})
                if not self.path.endswith("/chat/completions"):
                    self.send_error(404)
                    return
                text = server.reply(body)
                if isinstance(text, tuple):
                    status, content_type, raw = text
                    self.send_response(status)
                    self.send_header("Content-Type", content_type)
                    self.send_header("Content-Length", str(len(raw)))
                    self.end_headers()
                    self.wfile.write(raw)
                    return
                payload = json.dumps({
                    "id": f"chatcmpl-{len(server.requests)}", "object": "chat.completion",
                    "created": int(time.time()), "model": body["model"],
                    "choices": [{"index": 0, "finish_reason": "stop",
                                 "message": {"role": "assistant", "content": text}}],
                    "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2},
                }).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(payload)))
                self.end_headers()
                self.wfile.write(payload)

            def log_message(self, *args):
                pass

        self.httpd = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.base_url = f"http://127.0.0.1:{self.httpd.server_address[1]}/v1"
        # polled every 50 ms, not every 0.5 s: stop() waits for the poll (it answers requests at once either way)
        self.thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self.thread.start()

    def reply(self, body: dict) -> str:
        if callable(self.replies):
            return self.replies(body)
        return self.replies[min(len(self.requests) - 1, len(self.replies) - 1)]

    def stop(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def chat_server():
    """Factory: ``chat_server(replies) -> ChatServer``; every server is stopped after the test."""
    servers: list[ChatServer] = []

    def start(replies) -> ChatServer:
        servers.append(ChatServer(replies))
        return servers[-1]

    yield start
    for s in servers:
        s.stop()


class HungServer:
    """A TCP server on 127.0.0.1 that accepts every connection, reads nothing and never answers."""

    def __init__(self):
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.base_url = f"http://127.0.0.1:{self.sock.getsockname()[1]}/v1"
        self.connections: list[socket.socket] = []
        self.stopped = threading.Event()
        self.thread = threading.Thread(target=self._accept, daemon=True)
        self.thread.start()

    def _accept(self) -> None:
        while not self.stopped.is_set():
            try:
                self.connections.append(self.sock.accept()[0])
            except TimeoutError:
                continue
            except OSError:
                break

    def stop(self) -> None:
        self.stopped.set()
        self.thread.join(timeout=5)
        for conn in [*self.connections, self.sock]:
            conn.close()


@pytest.fixture
def hung_server():
    """A :class:`HungServer`, stopped after the test."""
    server = HungServer()
    yield server
    server.stop()


@pytest.fixture
def api_key(monkeypatch):
    """A fake API key in ``GRT_TEST_KEY``."""
    monkeypatch.setenv("GRT_TEST_KEY", API_KEY)
    return API_KEY


@pytest.fixture(scope="session")
def sphere() -> trimesh.Trimesh:
    """A 4 cm-radius icosphere (642 vertices), meters."""
    return trimesh.creation.icosphere(subdivisions=3, radius=0.04)


@pytest.fixture(scope="session")
def box() -> trimesh.Trimesh:
    """A 10 x 6 x 3 cm box, finely subdivided (mirror-symmetric about its principal planes)."""
    return trimesh.creation.box((0.10, 0.06, 0.03)).subdivide().subdivide().subdivide()
