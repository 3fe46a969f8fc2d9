"""The scene reading behind a provider (``ctp_core.assembly.readers``): the rules by default, an OpenAI-compatible
endpoint asked for the plan as JSON constrained by a schema (a scripted server on 127.0.0.1, no network), its answer
checked as the rules' reading is, and the rules as the fallback on any failure."""

from __future__ import annotations

import json

import pytest

from ctp_core.assembly.describe import read_description
from ctp_core.assembly.readers import OpenAIReader, ReaderSettings, RulesReader, get_reader, plan_schema
from ctp_core.errors import ConfigError
from ctp_core.priors import PriorSettings
from tests.test_priors import ChatServer

NAMES = ["writing desk", "storage box", "pedal bin", "chair"]
SENTENCE = "Two storage boxes go under the writing desk and the pedal bin next to them, with the chair in front."
ANSWER = {"objects": [
    {"name": "storage box", "count": 2, "relation": "under", "on": ["writing desk"]},
    {"name": "chair", "count": 1, "relation": "front", "on": ["writing desk"]},
    {"name": "pedal bin", "count": 1, "relation": "beside", "on": ["chair"]},
]}


def answering(content, status=200, delay=0.0):
    return lambda question: (status, content, delay)


def test_the_rules_are_the_default_reader_and_an_unknown_reader_is_refused(monkeypatch):
    monkeypatch.delenv("CTP_PLAN_READER", raising=False)
    assert isinstance(get_reader(), RulesReader) and ReaderSettings().reader == "rules"
    monkeypatch.setenv("CTP_PLAN_READER", "openai")
    assert get_reader().name == "openai"
    with pytest.raises(ConfigError) as caught:
        get_reader("oracle")
    assert caught.value.field == "reader"


def test_the_endpoint_is_asked_for_json_under_the_schema_and_its_answer_planned():
    with ChatServer(answering(json.dumps(ANSWER))) as server:
        plan = get_reader("openai", server.settings(model="qwen", api_key="sk-x")).read(SENTENCE, NAMES)
    request = server.requests[0]
    assert request["path"] == "/v1/chat/completions" and request["headers"]["Authorization"] == "Bearer sk-x"
    body = request["body"]
    assert body["model"] == "qwen" and body["response_format"]["type"] == "json_schema"
    assert body["response_format"]["json_schema"]["schema"] == plan_schema(NAMES)
    assert plan.reader == "openai" and plan.base == "writing desk" and not plan.warnings
    assert [(s.name, s.relation, s.on, s.support) for s in plan.steps] == [
        ("storage box_1", "under", ("writing desk",), "floor"), ("storage box_2", "under", ("writing desk",), "floor"),
        ("chair", "front", ("writing desk",), "floor"), ("pedal bin", "beside", ("chair",), "floor")]


def test_a_fenced_answer_with_a_think_block_is_read():
    content = "<think>the boxes first</think>\n```json\n" + json.dumps(ANSWER) + "\n```"
    with ChatServer(answering(content)) as server:
        assert get_reader("openai", server.settings()).read(SENTENCE, NAMES).reader == "openai"


@pytest.mark.parametrize(("content", "status", "why"), [
    ("the boxes go under the desk", 200, "AnswerError"),  # no JSON
    (json.dumps({"objects": [{"name": "sofa", "count": 1, "relation": "on", "on": ["chair"]}]}), 200,
     "none of the objects"),  # breaks the schema
    (json.dumps({"objects": [{"name": "chair", "count": 99, "relation": "on", "on": ["writing desk"]}]}), 200,
     "count must be"),  # a bound the schema says in words
    (json.dumps({"objects": [{"name": "chair", "count": 1, "relation": "on", "on": ["pedal bin"]},
                             {"name": "pedal bin", "count": 1, "relation": "on", "on": ["chair"]}]}), 200,
     "circle"),  # does not plan
    (json.dumps({"objects": [{"name": "chair", "count": 1, "relation": "between", "on": ["writing desk"]}]}), 200,
     "two objects"),
    (json.dumps(ANSWER), 500, "HTTPStatusError"),
])
def test_any_failure_falls_back_to_the_rules_and_says_why(content, status, why):
    with ChatServer(answering(content, status)) as server:
        plan = get_reader("openai", server.settings()).read(SENTENCE, NAMES)
    rules = read_description(SENTENCE, NAMES)
    assert plan.reader.startswith("rules (fallback: ") and why in plan.reader
    assert why in plan.warnings[0] and plan.warnings[1:] == rules.warnings
    assert [s.to_dict() for s in plan.steps] == [s.to_dict() for s in rules.steps]


def test_no_endpoint_and_a_slow_one_fall_back_fast():
    plan = OpenAIReader(PriorSettings(base_url=None)).read(SENTENCE, NAMES)
    assert plan.reader == "rules (fallback: no endpoint (CTP_LLM_BASE_URL unset))"
    with ChatServer(answering(json.dumps(ANSWER), delay=1.0)) as server:
        plan = get_reader("openai", server.settings(timeout_s=0.2, retries=0)).read(SENTENCE, NAMES)
    assert plan.reader.startswith("rules (fallback: ReadTimeout")


def test_compose_dry_run_reads_with_the_reader_it_is_given(tmp_path, monkeypatch, capsys):
    from ctp.cli import main

    files = []
    for name in NAMES:
        (tmp_path / f"{name.replace(' ', '_')}.glb").write_bytes(b"")
        files.append(str(tmp_path / f"{name.replace(' ', '_')}.glb"))
    with ChatServer(answering(json.dumps(ANSWER))) as server:
        for key, value in server.settings().model_dump().items():
            if value is not None:
                monkeypatch.setenv(f"CTP_LLM_{key.upper()}", str(value))
        assert main(["compose", *files, "--prompt", SENTENCE, "--reader", "openai", "--dry-run"]) == 0
    printed = capsys.readouterr().out
    assert "# read by openai" in printed and "pedal bin: beside chair" in printed
