"""VLM-guided handle selection: the paper's two-stage prompting (lines 219-250, 870-1060).

1. The heuristic keypoint sampler proposes ``K <= 25`` candidates (:mod:`grt.selectors.keypoints`).
2. *Geometric Reasoning*: the canonical view panel (:mod:`grt.selectors.panel`) and the keypoints'
   JSON (unit-cube coordinates, the frame drawn in the panel) go to the VLM, which answers
   :class:`~grt.selectors.prompts.Choices` (subsets of keypoint numbers with labels).
3. *Task-Critical Ranking*: with the stage-1 exchange replayed, the VLM picks the Pareto-best subset
   for the task (:class:`~grt.selectors.prompts.TopRank`); its keypoints are the handles.

Each answer is parsed and validated (JSON, schema, keypoint numbers in ``[0, K)``, non-empty); an
invalid answer is sent back with the validation error, at most ``max_retries`` times, then a
:class:`~grt.selectors.client.VLMError` names the config keys to check (and the cache folder, when a
cache is on). Only validated answers are cached, under the stage's question; a cached answer is
validated again when read, and one that fails is dropped and asked again (``cache="use"``) or refused
(``cache="replay"``). Each request waits at most ``timeout_s`` and all of a selection's requests end
within ``deadline_s``. Nothing falls back to the heuristic unless ``fallback="heuristic"`` is
configured, and then the reason is in the notes.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import time

import numpy as np
import trimesh
from pydantic import BaseModel, ValidationError

from grt.selectors.base import HandleSet
from grt.selectors.client import CONFIG_HINT, OpenAIChatClient, ResponseCache, VLMError
from grt.selectors.heuristic import HeuristicSelector, KeypointSelector
from grt.selectors.keypoints import Keypoints
from grt.selectors.panel import render_panel
from grt.selectors.prompts import (
    RETRY,
    Choices,
    HandlePoint,
    TopRank,
    geometric_reasoning_prompt,
    task_critical_ranking_prompt,
)

FALLBACKS = (None, "heuristic")


def parse_response(text: str, schema: type[BaseModel], num_keypoints: int) -> BaseModel:
    """Parse and validate one answer.

    Accepts bare JSON or JSON in a Markdown code fence; a stage-1 answer in the paper's numbered form
    (``{"0": {...}, "1": {...}}``, lines 975-995) is read as ``{"choices": [...]}``.

    Args:
        text: the model's reply.
        schema: :class:`Choices` or :class:`TopRank`.
        num_keypoints: ``K``; every keypoint number must lie in ``[0, K)``.

    Returns:
        The validated model, keypoint numbers de-duplicated in order.

    Raises:
        ValueError: with a message fit to be sent back to the model.
    """
    fenced = re.search(r"```(?:json)?\s*(.*?)```", text, flags=re.S)
    body = fenced.group(1) if fenced else text
    start, end = body.find("{"), body.rfind("}")
    if start < 0 or end < start:
        raise ValueError("the reply contains no JSON object")
    try:
        data = json.loads(body[start:end + 1])
    except json.JSONDecodeError as exc:
        raise ValueError(f"the reply is not valid JSON ({exc})") from None
    if schema is Choices and isinstance(data, dict) and data and all(k.isdigit() for k in data):
        data = {"choices": [data[k] for k in sorted(data, key=int)]}
    try:
        parsed = schema.model_validate(data)
    except ValidationError as exc:
        raise ValueError(f"the JSON does not match the schema: {exc}") from None
    subsets = parsed.choices if isinstance(parsed, Choices) else [parsed.top_choice]
    if not subsets:
        raise ValueError("no subset of keypoints was given")
    for subset in subsets:
        if not subset.keypoint_indices:
            raise ValueError(f"subset {subset.semantic_object_label!r} has no keypoint_indices")
        bad = [i for i in subset.keypoint_indices if not 0 <= i < num_keypoints]
        if bad:
            raise ValueError(f"keypoint indices {bad} are out of range: the keypoints are numbered "
                             f"0 to {num_keypoints - 1}")
        subset.keypoint_indices = list(dict.fromkeys(subset.keypoint_indices))
    return parsed


class VLMSelector(KeypointSelector):
    """Handles chosen by a vision-language model among the heuristic keypoints.

    Anchors follow :class:`~grt.selectors.heuristic.KeypointSelector`: candidate keypoints the VLM
    did not choose, protected regions, optional far-from-handle vertices, at least ``min_anchors``.

    Args:
        base_url: an OpenAI-compatible chat-completions endpoint.
        model: the model name (the paper used GPT-4o).
        api_key_env: name of the environment variable holding the API key (never the key itself).
        timeout_s: seconds per request (connecting, and each wait for the reply's bytes); a request
            that times out is not sent again.
        deadline_s: wall-clock seconds for all the requests of one :meth:`select` (both stages,
            re-asks included): the longest a slow or hung endpoint can hold a run.
        max_retries: re-asks per stage after an invalid answer (the error is sent back).
        cache: ``"use"``, ``"replay"`` (offline) or ``"off"`` (:class:`ResponseCache`).
        cache_dir: the exchange cache directory.
        fallback: ``None`` (errors propagate) or ``"heuristic"`` (a :class:`HeuristicSelector` with
            ``fallback_k`` handles; the reason is recorded in ``notes["fallback"]``).
        fallback_k: handles of the fallback.
        panel_px: panel width/height in pixels.
        temperature: sampling temperature.
        **kwargs: keypoint and anchor arguments of :class:`KeypointSelector`.
    """

    name = "vlm"

    def __init__(self, base_url: str = "https://api.openai.com/v1", model: str = "gpt-4o",
                 api_key_env: str = "OPENAI_API_KEY", timeout_s: float = 20.0, deadline_s: float = 60.0,
                 max_retries: int = 2, cache: str = "use", cache_dir: str = "~/.cache/grt/vlm",
                 fallback: str | None = None, fallback_k: int = 8, panel_px: int = 1024, temperature: float = 0.0,
                 **kwargs):
        super().__init__(**kwargs)
        if fallback not in FALLBACKS:
            raise ValueError(f"selector.fallback must be one of {FALLBACKS}, got {fallback!r}")
        if not float(deadline_s) > 0:
            raise ValueError(f"selector.deadline_s must be positive, got {deadline_s!r}")
        self.client = OpenAIChatClient(base_url, model, api_key_env, timeout_s, temperature)
        self.cache = ResponseCache(cache_dir, cache)
        self.max_retries, self.fallback, self.fallback_k = int(max_retries), fallback, int(fallback_k)
        self.panel_px, self.deadline_s = int(panel_px), float(deadline_s)

    def panel(self, mesh: trimesh.Trimesh, kp: Keypoints) -> bytes:
        """The canonical view panel of the candidates (PNG bytes)."""
        return render_panel(kp.frame.to_unit(mesh.vertices), mesh.faces, kp.positions, size_px=self.panel_px)

    def select(self, mesh: trimesh.Trimesh, task: str) -> HandleSet:
        """See :meth:`HandleSelector.select`.

        Raises:
            VLMError: unreachable or hung endpoint, missing API key, a replay-cache miss or unusable
                entry, or answers that never validate (unless ``fallback="heuristic"``).
        """
        try:
            return self._select(mesh, task)
        except VLMError as err:
            exc = self._naming_cache(err)
            if self.fallback != "heuristic":
                raise exc from None
            kwargs = dict(num_keypoints=self.num_keypoints, delta=self.delta, num_samples=self.num_samples,
                          protected=self.protected, far_anchors=self.far_anchors,
                          min_anchors=self.min_anchors, seed=self.seed)
            result = HeuristicSelector(k=self.fallback_k, **kwargs).select(mesh, task)
            notes = {**result.notes, "fallback": {"from": "vlm", "to": "heuristic", "reason": str(exc)}}
            return HandleSet(result.handles, result.anchors, notes)

    def _select(self, mesh: trimesh.Trimesh, task: str) -> HandleSet:
        kp = self.keypoints(mesh)
        png = self.panel(mesh, kp)
        url = "data:image/png;base64," + base64.b64encode(png).decode()
        log: list[dict] = []
        deadline = time.monotonic() + self.deadline_s
        stage1 = [{"role": "user", "content": [{"type": "text", "text": geometric_reasoning_prompt(kp.positions)},
                                               {"type": "image_url", "image_url": {"url": url}}]}]
        choices, reply1 = self._ask(stage1, Choices, len(kp), "geometric reasoning", log, deadline)
        stage2 = [*stage1, {"role": "assistant", "content": reply1},
                  {"role": "user", "content": task_critical_ranking_prompt(task)}]
        top, _ = self._ask(stage2, TopRank, len(kp), "task-critical ranking", log, deadline)
        best: HandlePoint = top.top_choice
        notes = {"task": task, "model": self.client.model, "base_url": self.client.base_url,
                 "panel_sha256": hashlib.sha256(png).hexdigest(),
                 "semantic_object_label": best.semantic_object_label,
                 "expected_transformations": best.expected_transformations,
                 "choices": [c.model_dump() for c in choices.choices], "exchanges": log}
        return self.handle_set(mesh, kp, np.asarray(best.keypoint_indices), notes)

    def _naming_cache(self, exc: VLMError) -> VLMError:
        """``exc`` with the cache folder named, when a cache is on and the message does not say it yet."""
        where = self.cache.describe()
        if not where or str(self.cache.directory) in str(exc):
            return exc
        return VLMError(f"{exc}; {where}")

    def _ask(self, messages: list[dict], schema: type[BaseModel], k: int, stage: str, log: list[dict],
             deadline: float) -> tuple[BaseModel, str]:
        """One stage: the cached answer if it validates, else up to ``max_retries + 1`` requests.

        Args:
            messages: the stage's question.
            schema: :class:`Choices` or :class:`TopRank`.
            k: the number of candidate keypoints.
            stage: the stage's name (for notes and messages).
            log: the exchange notes, appended to.
            deadline: :func:`time.monotonic` time by which every request must have ended.

        Returns:
            The parsed answer and its raw text. A validated answer from the endpoint is cached under
            ``messages`` (the stage's question, not the re-asks that led to it).
        """
        key = ResponseCache.key(self.client.model, messages)
        hit = self._cached(key, schema, k, stage, log)
        if hit is not None:
            return hit
        errors: list[str] = []
        asked = messages
        for attempt in range(self.max_retries + 1):
            text = self.client.complete(asked, timeout_s=self._remaining(deadline, stage, attempt, errors))
            log.append({"stage": stage, "attempt": attempt, "cache_key": key, "cached": False})
            try:
                parsed = parse_response(text, schema, k)
            except ValueError as exc:
                errors.append(str(exc))
                log[-1]["error"] = str(exc)
                retry = RETRY.format(error=exc, schema=json.dumps(schema.model_json_schema()))
                asked = [*asked, {"role": "assistant", "content": text}, {"role": "user", "content": retry}]
                continue
            self.cache.put(key, self.client.model, messages, text, self.client.base_url, attempt + 1)
            return parsed, text
        raise VLMError(f"the VLM's {stage} answer never validated after {self.max_retries + 1} attempts "
                       f"(selector.max_retries={self.max_retries}); last error: {errors[-1]}. Try a "
                       f"stronger model or more retries; {CONFIG_HINT}; nothing was cached")

    def _cached(self, key: str, schema: type[BaseModel], k: int, stage: str,
                log: list[dict]) -> tuple[BaseModel, str] | None:
        """The cached answer of a stage if it validates; an unusable one is dropped (or refused)."""
        try:
            text = self.cache.get(key)
            if text is None:
                return None
            parsed = parse_response(text, schema, k)
        except VLMError:  # a miss in replay mode is the user's to fix (a UserError, so a ValueError too)
            raise
        except ValueError as exc:  # CacheEntryError too
            note = self.cache.drop(key, f"{stage} answer: {exc}")
            log.append({"stage": stage, "cache_key": key, "cached": True, "dropped": note})
            return None
        log.append({"stage": stage, "attempt": 0, "cache_key": key, "cached": True})
        return parsed, text

    def _remaining(self, deadline: float, stage: str, attempt: int, errors: list[str]) -> float:
        """Seconds left of ``deadline_s`` for the next request; raises when none are."""
        left = deadline - time.monotonic()
        if left <= 0:
            last = f"; last error: {errors[-1]}" if errors else ""
            raise VLMError(f"selector.deadline_s={self.deadline_s:g} s spent before the VLM's {stage} answer "
                           f"validated ({attempt} attempts at this stage{last}); {CONFIG_HINT}, or raise "
                           "selector.deadline_s for a slow model")
        return left
