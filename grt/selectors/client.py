"""Chat-completions client for the VLM selector, and the on-disk cache of its exchanges.

Any OpenAI-compatible endpoint that accepts images (``image_url`` content parts with PNG data URLs)
works: OpenAI, Azure-compatible gateways, vLLM/SGLang/Ollama servers. Every request/response pair is
stored under the cache directory, keyed by a hash of the model and the messages (images included, as
their data URLs), so a selection can be replayed offline, bit for bit. The API key is read from an
environment variable when a request must really be sent, and is never written anywhere.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from pathlib import Path

CACHE_MODES = ("use", "replay", "off")
CONFIG_HINT = "check selector.base_url, selector.model and selector.api_key_env"


class VLMError(RuntimeError):
    """The VLM could not give a usable answer; the message names the config keys to fix."""


def _redact_images(messages: list[dict]) -> list[dict]:
    """Messages with every image data URL replaced by ``sha256:<hex>`` (for a readable cache file)."""
    out = []
    for msg in messages:
        content = msg["content"]
        if isinstance(content, list):
            content = [
                {"type": "image_url", "image_url": {"url": "sha256:" + hashlib.sha256(
                    part["image_url"]["url"].encode()).hexdigest()}} if part.get("type") == "image_url" else part
                for part in content
            ]
        out.append({**msg, "content": content})
    return out


class ResponseCache:
    """Request/response pairs on disk, one JSON file per request.

    Args:
        directory: where the files go (created on first write).
        mode: ``"use"`` (read-through: a hit is returned, a miss is sent and stored), ``"replay"``
            (offline only: a miss raises :class:`VLMError`), ``"off"`` (neither read nor written).
    """

    def __init__(self, directory: str | Path, mode: str = "use"):
        if mode not in CACHE_MODES:
            raise ValueError(f"selector.cache must be one of {CACHE_MODES}, got {mode!r}")
        self.directory, self.mode = Path(directory).expanduser(), mode

    @staticmethod
    def key(model: str, messages: list[dict]) -> str:
        """SHA-256 of the canonical JSON of ``(model, messages)``; images are inside the messages."""
        blob = json.dumps({"model": model, "messages": messages}, sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(blob.encode()).hexdigest()

    def path(self, key: str) -> Path:
        return self.directory / f"{key}.json"

    def get(self, key: str) -> str | None:
        """The stored response text, or ``None`` (a miss in ``replay`` mode raises)."""
        if self.mode == "off":
            return None
        path = self.path(key)
        if path.is_file():
            return json.loads(path.read_text())["response"]
        if self.mode == "replay":
            raise VLMError(f"selector.cache=replay but no cached response {key[:16]}... in {self.directory}; "
                           "run once with selector.cache=use against a reachable endpoint, or point "
                           "selector.cache_dir at the cache that holds the exchange")
        return None

    def put(self, key: str, model: str, messages: list[dict], response: str, base_url: str | None = None) -> None:
        """Store one exchange (images stored as their hashes; no credentials)."""
        if self.mode != "use":
            return
        self.directory.mkdir(parents=True, exist_ok=True)
        record = {"key": key, "model": model, "base_url": base_url, "created": time.time(),
                  "messages": _redact_images(messages), "response": response}
        tmp = self.path(key).with_suffix(".tmp")
        tmp.write_text(json.dumps(record, indent=1))
        tmp.replace(self.path(key))


class OpenAIChatClient:
    """Chat completions over the ``openai`` package.

    Args:
        base_url: the endpoint (``https://api.openai.com/v1``, ``http://127.0.0.1:8000/v1``, ...).
        model: the model name the endpoint serves.
        api_key_env: name of the environment variable holding the key (read at the first request).
        timeout_s: seconds per request.
        temperature: sampling temperature (0: as repeatable as the endpoint allows).
    """

    def __init__(self, base_url: str, model: str, api_key_env: str = "OPENAI_API_KEY",
                 timeout_s: float = 120.0, temperature: float = 0.0):
        self.base_url, self.model, self.api_key_env = base_url, model, api_key_env
        self.timeout_s, self.temperature = float(timeout_s), float(temperature)
        self._client = None
        self._key = ""

    def _connect(self):
        if self._client is None:
            import openai

            self._key = os.environ.get(self.api_key_env, "")
            if not self._key:
                raise VLMError(f"the environment variable {self.api_key_env!r} named by selector.api_key_env "
                               "is not set: export the API key there, or set selector.api_key_env to the "
                               "variable that holds it (any non-empty value for a local server that needs "
                               "none), or use selector.cache=replay with a filled cache")
            self._client = openai.OpenAI(base_url=self.base_url, api_key=self._key,
                                         timeout=self.timeout_s, max_retries=0)
        return self._client

    def complete(self, messages: list[dict]) -> str:
        """Send one chat-completions request; the assistant's text (``""`` when it has none)."""
        import openai

        client = self._connect()
        where = f"selector.base_url={self.base_url!r}, selector.model={self.model!r}"
        try:
            resp = client.chat.completions.create(model=self.model, messages=messages,
                                                  temperature=self.temperature)
        except openai.AuthenticationError as exc:
            raise VLMError(self._scrub(f"the endpoint rejected the API key in ${self.api_key_env} "
                                       f"(selector.api_key_env; {where}): {exc}")) from None
        except openai.NotFoundError as exc:
            raise VLMError(self._scrub(f"not found at the endpoint ({where}); {CONFIG_HINT}: {exc}")) from None
        except (openai.APIConnectionError, openai.APITimeoutError) as exc:
            raise VLMError(self._scrub(f"could not reach the VLM endpoint ({where}, "
                                       f"selector.timeout_s={self.timeout_s}); {CONFIG_HINT}: {exc}")) from None
        except openai.APIError as exc:
            raise VLMError(self._scrub(f"the VLM endpoint failed ({where}); {CONFIG_HINT}: {exc}")) from None
        if not resp.choices:
            return ""
        return resp.choices[0].message.content or ""

    def _scrub(self, text: str) -> str:
        return text.replace(self._key, "***") if self._key else text
