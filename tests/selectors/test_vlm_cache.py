"""The VLM selector's cache and time limits against local servers: only validated answers are cached,
unusable cached answers are re-asked (``use``) or refused (``replay``), a hung endpoint fails fast."""

from __future__ import annotations

import json
import logging
import time

import pytest

from grt.selectors.client import VLMError
from grt.selectors.vlm import VLMSelector

TASK = "grasp the object, lift it and shake it"
SUBSET = {"keypoint_indices": [1, 3], "semantic_object_label": "side wall",
          "expected_transformations": ["bulge the side"]}
STAGE1 = json.dumps({"choices": [SUBSET]})
STAGE2 = json.dumps({"top_choice": SUBSET})


def make(base_url: str, tmp_path, **kw) -> VLMSelector:
    args = dict(base_url=base_url, model="test-vlm", api_key_env="GRT_TEST_KEY", timeout_s=5,
                cache_dir=str(tmp_path / "cache"), panel_px=256, num_samples=5000)
    return VLMSelector(**{**args, **kw})


def cache_files(tmp_path) -> dict[int, object]:
    """The cache's files by the number of messages of their question (1: stage 1, 3: stage 2)."""
    files = sorted((tmp_path / "cache").glob("*.json"))
    return {len(json.loads(p.read_text())["messages"]): p for p in files}


@pytest.mark.parametrize("bad", [
    "I'm sorry, I cannot see the image.",
    "",
    (200, "application/json", json.dumps({"error": {"message": "model 'test-vlm' is not loaded"}}).encode()),
    (200, "text/html", b"<html><body>Welcome to nginx!</body></html>"),
    (200, "application/json", b'{"choices": [{"mess'),
], ids=["invalid-answer", "empty", "error-body", "html", "garbled"])
def test_bad_endpoint_leaves_nothing_cached_for_the_next_run(bad, chat_server, api_key, sphere, tmp_path):
    broken = chat_server([bad])
    with pytest.raises(VLMError) as info:
        make(broken.base_url, tmp_path).select(sphere, TASK)
    message = str(info.value)
    assert str(tmp_path / "cache") in message and "selector.cache=use" in message and "\n" not in message
    assert len(broken.requests) >= 1 and not list((tmp_path / "cache").glob("*.json"))

    good = chat_server([STAGE1, STAGE2])
    hs = make(good.base_url, tmp_path).select(sphere, TASK)
    assert hs.notes["semantic_object_label"] == "side wall"
    assert len(good.requests) == 2 and not any(e["cached"] for e in hs.notes["exchanges"])
    assert set(cache_files(tmp_path)) == {1, 3}


def test_reasked_answer_is_cached_under_the_stage_question(chat_server, api_key, sphere, tmp_path, monkeypatch):
    server = chat_server(["no idea", STAGE1, STAGE2])
    make(server.base_url, tmp_path).select(sphere, TASK)
    assert len(server.requests) == 3
    record = json.loads(cache_files(tmp_path)[1].read_text())
    assert record["response"] == STAGE1 and record["attempts"] == 2
    # the validated answer replays offline although the first answer to the question was invalid
    server.stop()
    monkeypatch.delenv("GRT_TEST_KEY")
    hs = make(server.base_url, tmp_path, cache="replay").select(sphere, TASK)
    assert hs.notes["semantic_object_label"] == "side wall"


@pytest.mark.parametrize("corrupt", ["invalid-answer", "not-json", "no-response"])
def test_unusable_cache_entry_is_reasked_in_use_and_refused_in_replay(corrupt, chat_server, api_key, sphere,
                                                                     tmp_path, caplog):
    make(chat_server([STAGE1, STAGE2]).base_url, tmp_path).select(sphere, TASK)
    stage1 = cache_files(tmp_path)[1]
    record = json.loads(stage1.read_text())
    if corrupt == "invalid-answer":
        stage1.write_text(json.dumps({**record, "response": json.dumps({"choices": [
            {**SUBSET, "keypoint_indices": [999]}]})}))
    elif corrupt == "not-json":
        stage1.write_text(stage1.read_text()[:100])
    else:
        stage1.write_text(json.dumps({k: v for k, v in record.items() if k != "response"}))

    with pytest.raises(VLMError) as info:
        make("http://127.0.0.1:9/v1", tmp_path, cache="replay").select(sphere, TASK)
    message = str(info.value)
    assert str(stage1) in message and "selector.cache=replay" in message and "\n" not in message
    assert "delete that file" in message and "selector.cache=use" in message
    assert stage1.is_file()  # replay never changes the cache

    server = chat_server([STAGE1])
    with caplog.at_level(logging.WARNING, logger="grt.selectors.client"):
        hs = make(server.base_url, tmp_path).select(sphere, TASK)
    assert len(server.requests) == 1  # stage 1 re-asked; stage 2 (same question) still cached
    dropped = [e for e in hs.notes["exchanges"] if "dropped" in e]
    assert len(dropped) == 1 and str(stage1) in dropped[0]["dropped"]
    assert "dropped unusable cached answer" in caplog.text
    assert json.loads(stage1.read_text())["response"] == STAGE1
    assert make("http://127.0.0.1:9/v1", tmp_path, cache="replay").select(sphere, TASK).handles.size == 2


def test_hung_endpoint_fails_within_the_deadline(hung_server, api_key, sphere, tmp_path, monkeypatch):
    selector = make(hung_server.base_url, tmp_path, timeout_s=30, deadline_s=1.0)
    sent: list[float] = []
    complete = selector.client.complete

    def timed(messages, timeout_s=None):
        sent.append(time.monotonic())
        return complete(messages, timeout_s=timeout_s)

    monkeypatch.setattr(selector.client, "complete", timed)
    with pytest.raises(VLMError) as info:
        selector.select(sphere, TASK)
    elapsed = time.monotonic() - sent[0]
    message = str(info.value)
    assert len(sent) == 1 and 0.9 < elapsed < 3, elapsed  # 1 s, with room for a busy machine
    assert "did not answer within" in message and "selector.deadline_s" in message
    assert str(tmp_path / "cache") in message and "\n" not in message
    assert hung_server.connections  # the request really went out


def test_hung_endpoint_fails_after_one_request_timeout(hung_server, api_key, sphere, tmp_path):
    start = time.monotonic()
    with pytest.raises(VLMError, match=r"did not answer within 0.5 s \(selector.timeout_s=0.5"):
        make(hung_server.base_url, tmp_path, timeout_s=0.5, max_retries=5).select(sphere, TASK)
    assert time.monotonic() - start < 4
    assert len(hung_server.connections) == 1  # a timed-out request is not sent again


def test_deadline_bounds_slow_invalid_answers(chat_server, api_key, sphere, tmp_path):
    def slow_and_wrong(_body):
        time.sleep(0.3)
        return "thinking..."

    server = chat_server(slow_and_wrong)
    start = time.monotonic()
    with pytest.raises(VLMError, match="selector.deadline_s"):
        make(server.base_url, tmp_path, max_retries=50, deadline_s=1.0).select(sphere, TASK)
    assert time.monotonic() - start < 5
    assert 2 <= len(server.requests) <= 5


def test_defaults_fail_a_hung_endpoint_well_under_a_minute(tmp_path):
    selector = VLMSelector(cache_dir=str(tmp_path))
    assert selector.client.timeout_s <= 30 and selector.deadline_s <= 60
    with pytest.raises(ValueError, match="selector.deadline_s"):
        VLMSelector(cache_dir=str(tmp_path), deadline_s=0)
