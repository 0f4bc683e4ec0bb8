"""Chat-completions client for the VLM selector, and the on-disk cache of its validated answers.

Any OpenAI-compatible endpoint that accepts images (``image_url`` content parts with PNG data URLs)
works: OpenAI, Azure-compatible gateways, vLLM/SGLang/Ollama servers. The API key is read from an
environment variable when a request must really be sent, and is never written anywhere.

The cache holds one JSON file per stage question, keyed by a hash of the model and the stage's
messages (images included, as their data URLs), so a selection can be replayed offline, bit for bit.
Only answers that passed the stage's validation are written: an invalid answer, an error body or an
empty reply never is, so a misconfigured endpoint leaves nothing behind for the next run to replay.
A stored answer that fails validation when read back is dropped (``use``) or refused (``replay``),
see :meth:`ResponseCache.drop`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import time
from pathlib import Path

from grt.errors import UserError
from grt.fileio import write_text_atomic

log = logging.getLogger(__name__)

CACHE_MODES = ("use", "replay", "off")
CONFIG_HINT = "check selector.base_url, selector.model and selector.api_key_env"


class VLMError(UserError, RuntimeError):  # RuntimeError: what caught it before still does
    """The VLM could not give a usable answer; the message (one line) names the config keys to fix."""

    def __init__(self, message: str):
        super().__init__(" ".join(str(message).split()))


class CacheEntryError(ValueError):
    """A cache file that cannot be read back as an exchange record."""


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
    """Validated answers on disk, one JSON file per stage question.

    Args:
        directory: where the files go (created on first write).
        mode: ``"use"`` (read-through: a hit is returned, a miss is asked and its validated answer
            stored), ``"replay"`` (offline only: a miss or an unusable entry raises
            :class:`VLMError`), ``"off"`` (neither read nor written).
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

    def describe(self) -> str:
        """One clause naming the cache for error messages (empty when the cache is off)."""
        if self.mode == "off":
            return ""
        return (f"VLM cache: {self.directory} (selector.cache={self.mode}, selector.cache_dir; it holds only "
                "validated answers)")

    def get(self, key: str) -> str | None:
        """The stored answer text, or ``None`` on a miss.

        Raises:
            VLMError: a miss in ``replay`` mode.
            CacheEntryError: the file exists but is not a readable record (pass it to :meth:`drop`).
        """
        if self.mode == "off":
            return None
        path = self.path(key)
        if path.is_file():
            try:
                response = json.loads(path.read_text())["response"]
            except (OSError, ValueError, KeyError, TypeError) as exc:
                raise CacheEntryError(f"unreadable cache file ({type(exc).__name__}: {exc})") from None
            if not isinstance(response, str):
                raise CacheEntryError(f"cache file holds a {type(response).__name__} response, not text")
            return response
        if self.mode == "replay":
            raise VLMError(f"selector.cache=replay but no cached answer {key[:16]}... in {self.directory}; "
                           "run once with selector.cache=use against a reachable endpoint, or point "
                           "selector.cache_dir at the cache that holds the exchange")
        return None

    def drop(self, key: str, reason: str) -> str:
        """Deal with a stored answer that cannot be used (unreadable, or fails the stage's validation).

        In ``use`` mode the file is deleted (so the question is asked again) and a note returned; in
        ``replay`` mode nothing can be asked, so this raises.

        Raises:
            VLMError: in ``replay`` mode, naming the file and the two ways out.
        """
        path = self.path(key)
        if self.mode == "replay":
            raise VLMError(f"selector.cache=replay but the cached answer {path} is unusable ({reason}); "
                           "delete that file and run once with selector.cache=use against a reachable "
                           "endpoint to ask again, or point selector.cache_dir at a cache with a good answer")
        path.unlink(missing_ok=True)
        note = f"dropped unusable cached answer {path} ({reason}); asking the endpoint again"
        log.warning(" ".join(note.split()))
        return note

    def put(self, key: str, model: str, messages: list[dict], response: str, base_url: str | None = None,
            attempts: int = 1) -> None:
        """Store one validated answer (images stored as their hashes; no credentials).

        Args:
            key: :meth:`key` of ``(model, messages)``.
            model: the model name.
            messages: the stage's question (without the re-asks that may have led to ``response``).
            response: the answer text, already validated by the caller.
            base_url: the endpoint that answered (a record, not part of the key).
            attempts: requests it took (re-asks after invalid answers included).
        """
        if self.mode != "use":
            return
        self.directory.mkdir(parents=True, exist_ok=True)
        record = {"key": key, "model": model, "base_url": base_url, "created": time.time(), "attempts": attempts,
                  "messages": _redact_images(messages), "response": response}
        write_text_atomic(self.path(key), json.dumps(record, indent=1))


def _content_text(content) -> str:
    """The text of a message's ``content`` (a string, or a list of content parts)."""
    if isinstance(content, str):
        return content
    if isinstance(content, list):
        return "".join(p.get("text", "") for p in content if isinstance(p, dict) and p.get("type") == "text")
    return ""


class OpenAIChatClient:
    """Chat completions over the ``openai`` package.

    Args:
        base_url: the endpoint (``https://api.openai.com/v1``, ``http://127.0.0.1:8000/v1``, ...).
        model: the model name the endpoint serves.
        api_key_env: name of the environment variable holding the key (read at the first request).
        timeout_s: seconds per request for connecting, sending and each wait for the reply's bytes.
            A request that times out is not sent again.
        temperature: sampling temperature (0: as repeatable as the endpoint allows).
    """

    def __init__(self, base_url: str, model: str, api_key_env: str = "OPENAI_API_KEY",
                 timeout_s: float = 20.0, temperature: float = 0.0):
        self.base_url, self.model, self.api_key_env = base_url, model, api_key_env
        self.timeout_s, self.temperature = float(timeout_s), float(temperature)
        if self.timeout_s <= 0:
            raise ValueError(f"selector.timeout_s must be positive, got {timeout_s!r}")
        self._client = None
        self._key = ""

    @property
    def where(self) -> str:
        return f"selector.base_url={self.base_url!r}, selector.model={self.model!r}"

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

    def complete(self, messages: list[dict], timeout_s: float | None = None) -> str:
        """Send one chat-completions request; the assistant's text (``""`` when it has none).

        Args:
            messages: the chat messages.
            timeout_s: this request's timeout (at most ``self.timeout_s``; a deadline's remainder).

        Raises:
            VLMError: the endpoint is unreachable, timed out, refused the request, or its reply is
                not a chat completion (an error body, HTML, garbled JSON).
        """
        import openai

        client = self._connect()
        timeout = min(self.timeout_s, timeout_s) if timeout_s is not None else self.timeout_s
        try:
            raw = client.chat.completions.with_raw_response.create(
                model=self.model, messages=messages, temperature=self.temperature, timeout=timeout)
            body = raw.http_response.text
        except openai.AuthenticationError as exc:
            raise self._error(f"the endpoint rejected the API key in ${self.api_key_env} "
                              f"(selector.api_key_env; {self.where}): {exc}") from None
        except openai.NotFoundError as exc:
            raise self._error(f"not found at the endpoint ({self.where}); {CONFIG_HINT}: {exc}") from None
        except openai.APITimeoutError:
            limit = (f"selector.timeout_s={self.timeout_s:g}" if timeout >= self.timeout_s
                     else "what was left of selector.deadline_s")
            raise self._error(f"the VLM endpoint did not answer within {timeout:.3g} s ({limit}; {self.where}); "
                              "the request was not sent again: check that the server is up and serving, or "
                              "raise selector.timeout_s and selector.deadline_s for a slow model") from None
        except openai.APIConnectionError as exc:
            raise self._error(f"could not reach the VLM endpoint ({self.where}, "
                              f"selector.timeout_s={self.timeout_s:g}); {CONFIG_HINT}: {exc}") from None
        except openai.APIError as exc:
            raise self._error(f"the VLM endpoint failed ({self.where}); {CONFIG_HINT}: {exc}") from None
        return self._parse(body)

    def _parse(self, body: str) -> str:
        """The assistant's text in a chat-completion body; anything else is a :class:`VLMError`."""
        try:
            data = json.loads(body)
        except ValueError:
            data = None
        if isinstance(data, dict) and isinstance(data.get("choices"), list):
            if not data["choices"]:
                return ""
            choice = data["choices"][0]
            message = choice.get("message") if isinstance(choice, dict) else None
            if isinstance(message, dict):
                return _content_text(message.get("content"))
        if isinstance(data, dict) and data.get("error"):
            error = data["error"]
            detail = error.get("message", error) if isinstance(error, dict) else error
            raise self._error(f"the VLM endpoint answered with an error ({self.where}); {CONFIG_HINT}: {detail}")
        raise self._error(f"the VLM endpoint's reply is not a chat completion ({self.where}); {CONFIG_HINT}; "
                          f"the reply starts with {body[:200]!r}")

    def _error(self, text: str) -> VLMError:
        return VLMError(text.replace(self._key, "***") if self._key else text)
