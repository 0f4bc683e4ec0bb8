"""The VLM selector against a local chat-completions server (no network, no real model)."""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

from grt.selectors.client import VLMError
from grt.selectors.keypoints import sample_keypoints
from grt.selectors.prompts import GEOMETRIC_REASONING, Choices, TopRank
from grt.selectors.vlm import VLMSelector, parse_response

TASK = "grasp the object, lift it and shake it"
STAGE1 = json.dumps({"choices": [
    {"keypoint_indices": [0, 2, 4], "semantic_object_label": "top rim",
     "expected_transformations": ["flare the rim"]},
    {"keypoint_indices": [1, 3], "semantic_object_label": "side wall",
     "expected_transformations": ["bulge the side"]}]})
STAGE2 = json.dumps({"top_choice": {"keypoint_indices": [3, 1], "semantic_object_label": "side wall",
                                    "expected_transformations": ["bulge the side"]}})


def make(server, tmp_path, **kw) -> VLMSelector:
    args = dict(base_url=server.base_url if server else "http://127.0.0.1:9/v1", model="test-vlm",
                api_key_env="GRT_TEST_KEY", timeout_s=5, cache_dir=str(tmp_path / "cache"), panel_px=256,
                num_samples=5000)
    return VLMSelector(**{**args, **kw})


def test_two_stage_exchange_yields_the_chosen_handles(chat_server, api_key, sphere, tmp_path):
    server = chat_server([STAGE1, STAGE2])
    hs = make(server, tmp_path).select(sphere, TASK)
    kp = sample_keypoints(sphere, num_samples=5000)
    assert sorted(hs.handles) == sorted(kp.vertices[[3, 1]])
    assert set(hs.anchors) == set(kp.vertices) - set(hs.handles)
    assert hs.notes["semantic_object_label"] == "side wall"
    assert len(server.requests) == 2 and server.headers[0]["authorization"] == f"Bearer {api_key}"
    first, second = server.requests
    text, image = first["messages"][0]["content"]
    assert text["text"].startswith(GEOMETRIC_REASONING.split("{")[0])
    assert f'"index": {len(kp) - 1}' in text["text"]
    png = base64.b64decode(image["image_url"]["url"].split(",", 1)[1])
    assert png[:4] == b"\x89PNG"
    # stage 2 replays the stage-1 exchange, then asks for the ranking naming the task
    assert second["messages"][:2] == [first["messages"][0], {"role": "assistant", "content": STAGE1}]
    assert TASK in second["messages"][2]["content"] and "pareto" in second["messages"][2]["content"]


def test_malformed_then_valid_is_retried_with_the_error(chat_server, api_key, sphere, tmp_path):
    server = chat_server(["Sure! here it is: {not: json}", "```json\n" + STAGE1 + "\n```", STAGE2])
    hs = make(server, tmp_path).select(sphere, TASK)
    assert len(hs.handles) == 2 and len(server.requests) == 3
    feedback = server.requests[1]["messages"][-1]["content"]
    assert "not valid JSON" in feedback and "keypoint_indices" in feedback


def test_out_of_range_indices_exhaust_retries(chat_server, api_key, sphere, tmp_path):
    bad = json.dumps({"choices": [{"keypoint_indices": [999], "semantic_object_label": "x",
                                   "expected_transformations": []}]})
    server = chat_server([bad])
    with pytest.raises(VLMError, match=r"never validated.*selector.max_retries.*out of range.*selector.model"):
        make(server, tmp_path, max_retries=2).select(sphere, TASK)
    assert len(server.requests) == 3


def test_parse_response_schemas():
    paper_form = json.dumps({"0": json.loads(STAGE1)["choices"][0]})
    assert parse_response(paper_form, Choices, 5).choices[0].keypoint_indices == [0, 2, 4]
    dup = json.dumps({"top_choice": {"keypoint_indices": [1, 1, 2], "semantic_object_label": "a",
                                     "expected_transformations": []}})
    assert parse_response(dup, TopRank, 3).top_choice.keypoint_indices == [1, 2]
    for text, err in [('{"choices": []}', "no subset"), ('{"top": 1}', "schema"), ("no json", "no JSON")]:
        with pytest.raises(ValueError, match=err):
            parse_response(text, Choices if "choices" in text or err == "no JSON" else TopRank, 5)


def test_replay_from_cache_with_the_server_stopped(chat_server, api_key, sphere, tmp_path, monkeypatch):
    server = chat_server([STAGE1, STAGE2])
    live = make(server, tmp_path).select(sphere, TASK)
    server.stop()
    monkeypatch.delenv("GRT_TEST_KEY")
    replayed = make(server, tmp_path, cache="replay").select(sphere, TASK)
    np.testing.assert_array_equal(live.handles, replayed.handles)
    assert all(e["cached"] for e in replayed.notes["exchanges"])
    with pytest.raises(VLMError, match="selector.cache=replay"):
        make(server, tmp_path, cache="replay").select(sphere, "insert the plug")


def test_missing_key_and_unreachable_endpoint_are_clear_errors(sphere, tmp_path, monkeypatch):
    monkeypatch.delenv("GRT_TEST_KEY", raising=False)
    with pytest.raises(VLMError, match="GRT_TEST_KEY.*selector.api_key_env"):
        make(None, tmp_path).select(sphere, TASK)
    monkeypatch.setenv("GRT_TEST_KEY", "sk-x")
    with pytest.raises(VLMError, match=r"could not reach.*selector.base_url.*selector.model"):
        make(None, tmp_path, timeout_s=2).select(sphere, TASK)


def test_fallback_only_when_configured_and_recorded(sphere, tmp_path, monkeypatch):
    monkeypatch.delenv("GRT_TEST_KEY", raising=False)
    hs = make(None, tmp_path, fallback="heuristic", fallback_k=4).select(sphere, TASK)
    assert len(hs.handles) == 4
    assert "selector.api_key_env" in hs.notes["fallback"]["reason"]


def test_api_key_never_written(chat_server, api_key, sphere, tmp_path):
    from grt.cli.select import select

    server = chat_server([STAGE1, STAGE2])
    select_out = tmp_path / "out"
    path = tmp_path / "sphere.stl"
    sphere.export(path)
    record = select(str(path), TASK, make(server, tmp_path), select_out)
    assert record["semantic_object_label"] == "side wall" and len(record["handle_positions"]) == 2
    files = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert any(p.parent.name == "cache" for p in files) and (select_out / "handles.json").is_file()
    for p in files:
        assert api_key.encode() not in p.read_bytes(), p
