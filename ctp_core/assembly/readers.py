"""Who reads a description into a plan: the rules (``describe.read_description``: the default, and the fallback) or a
language model behind any OpenAI-compatible chat-completions endpoint.

The same shape as the priors' providers (``ctp_core.priors``): ``get_reader("rules")`` or ``get_reader("openai")``,
the endpoint set by the priors' settings (``CTP_LLM_BASE_URL``, ``CTP_LLM_MODEL``, ``CTP_LLM_API_KEY``,
``CTP_LLM_TIMEOUT_S``, ``CTP_LLM_RETRIES``), the reader by ``CTP_PLAN_READER`` (``rules`` unless set) or by the
caller (``ctp compose --reader``). The model is asked for the relations of the scene as JSON constrained by a JSON
schema (``response_format`` ``json_schema``: every object one of the uploads' names, every relation one of the
reader's), and what it answers is planned and checked as the rules' reading is (``describe.plan_relations``: every
object placed once, no circle, each step's prompt read back by the pair reader as the relation the model gave,
``check_plan``). Any failure (no endpoint, a refused connection, a timeout, an HTTP error, an answer that is no
JSON, breaks the schema or does not plan) falls back to the rules, and the plan says why (``reader``, and a warning):
a scene is never refused for a flaky endpoint. The rule reader is what the acceptance measures.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol

from pydantic_settings import BaseSettings, SettingsConfigDict

from ctp_core.assembly.describe import ScenePlan, keys_of, plan_relations, read_description
from ctp_core.assembly.plan import MAX_GROUNDS, check_plan
from ctp_core.errors import ConfigError
from ctp_core.priors.openai import PriorSettings
from ctp_core.reading.counts import MAX_COPIES
from ctp_core.reading.records import RelationName
from ctp_core.reading.scene import Said, SceneReading

if TYPE_CHECKING:  # imported where an endpoint is asked: the rules (the default) never load it
    import httpx

__all__ = ["READERS", "RELATION_WORDS", "OpenAIReader", "PlanReader", "ReaderSettings", "RulesReader", "get_reader",
           "plan_schema"]

READERS = ("rules", "openai")
R = RelationName
# The relations a model may give, each with the words a step's prompt says it with (the figure before them).
RELATION_WORDS: dict[RelationName, str] = {
    R.ON: "on", R.IN: "in", R.UNDER: "under", R.BESIDE: "beside", R.FRONT: "in front of", R.BEHIND: "behind",
    R.LEFT: "to the left of", R.RIGHT: "to the right of", R.ABOVE: "above", R.BELOW: "below", R.NEAR: "near",
    R.FAR: "far from", R.FACING: "facing", R.FACING_AWAY: "facing away from", R.BETWEEN: "between",
    R.LEAN: "leaning against", R.HANG: "hanging from", R.ATTACH: "attached to",
}
del R
FLOOR = "floor"  # the relation of an object said to stand on the floor
SYSTEM = ("You read a description of a 3D scene into the relations between its objects. Answer with one JSON object "
          "that follows the schema and nothing else.")
QUESTION = (
    "Scene: \"{description}\"\nThe objects (use these names exactly): {names}.\nFor every object the description "
    "places, give its name, how many copies the description asks for (count), its relation and the objects it is "
    "placed relative to (on: one object, two for \"between\"; for \"floor\", none). A relation said of a group "
    "(\"next to them\") names both objects. Relations: {relations}. The object everything stands on or around "
    "is not placed: leave it out.")


class ReaderSettings(BaseSettings):
    """Which reader reads descriptions; from the environment (``CTP_PLAN_READER``)."""

    model_config = SettingsConfigDict(env_prefix="CTP_PLAN_", extra="ignore")

    reader: str = "rules"


class PlanReader(Protocol):
    """Reads a description over the uploads' names into a plan."""

    name: str

    def read(self, description: str, names: Sequence[str]) -> ScenePlan: ...


class RulesReader:
    """The rule reader (``describe.read_description``)."""

    name = "rules"

    def read(self, description: str, names: Sequence[str]) -> ScenePlan:
        return read_description(description, names)


def get_reader(name: str | None = None, settings: PriorSettings | None = None) -> PlanReader:
    """A reader by name (None: ``CTP_PLAN_READER``, else the rules); ``settings`` (default: from ``CTP_LLM_*``)
    configure "openai"."""
    name = name or ReaderSettings().reader
    if name == "rules":
        return RulesReader()
    if name == "openai":
        return OpenAIReader(settings or PriorSettings())
    raise ConfigError(f"unknown plan reader {name!r}; choose one of {', '.join(READERS)}", field="reader")


def plan_schema(names: Sequence[str]) -> dict[str, Any]:
    """The JSON schema of the answer: the relations of the objects called ``names`` (only the keywords strict
    structured outputs accept; the bounds said in descriptions are checked on the answer, ``_check``)."""
    called = list(dict.fromkeys(" ".join(n.split()) for n in names))
    return {
        "type": "object", "additionalProperties": False, "required": ["objects"],
        "properties": {"objects": {"type": "array", "items": {
            "type": "object", "additionalProperties": False, "required": ["name", "count", "relation", "on"],
            "properties": {
                "name": {"type": "string", "enum": called},
                "count": {"type": "integer", "description": f"1 to {MAX_COPIES}"},
                "relation": {"type": "string", "enum": [*map(str, RELATION_WORDS), FLOOR]},
                "on": {"type": "array", "items": {"type": "string", "enum": called},
                       "description": f"at most {MAX_GROUNDS}"},
            }}}},
    }


class AnswerError(ValueError):
    """The model's answer is not a plan: no JSON, or JSON the schema does not allow."""


class OpenAIReader:
    """Asks the endpoint for the scene's relations; on any failure reads with the rules and says so."""

    name = "openai"

    def __init__(self, settings: PriorSettings, fallback: PlanReader | None = None) -> None:
        self.settings = settings
        self.fallback = fallback or RulesReader()

    def read(self, description: str, names: Sequence[str]) -> ScenePlan:
        if not self.settings.base_url:
            return self._fall_back(description, names, "no endpoint (CTP_LLM_BASE_URL unset)")
        import httpx

        try:
            answer = self._ask(description, names)
            plan = plan_answer(description, names, answer)
        except (httpx.HTTPError, AnswerError, ConfigError) as exc:  # a DescriptionError is a ConfigError
            why = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
            return self._fall_back(description, names, why)
        plan.reader = self.name
        return plan

    def _ask(self, description: str, names: Sequence[str]) -> Any:
        """The answer's JSON, the question retried on any failure; the last failure propagates."""
        question = QUESTION.format(description=description, names=", ".join(f'"{n}"' for n in names),
                                   relations=", ".join([*map(str, RELATION_WORDS), FLOOR]))
        body: dict[str, Any] = {
            "messages": [{"role": "system", "content": SYSTEM}, {"role": "user", "content": question}],
            "temperature": 0, "max_tokens": 1024,
            "response_format": {"type": "json_schema", "json_schema": {
                "name": "scene_plan", "strict": True, "schema": plan_schema(names)}}}
        if self.settings.model:
            body["model"] = self.settings.model
        key = self.settings.api_key
        headers = {"Authorization": f"Bearer {key.get_secret_value()}"} if key else {}
        import httpx

        failure: Exception | None = None
        with httpx.Client(base_url=self.settings.base_url.rstrip("/") + "/",  # type: ignore[union-attr]
                          timeout=self.settings.timeout_s, headers=headers) as client:
            for _ in range(self.settings.retries + 1):
                try:
                    response = client.post("chat/completions", json=body)
                    response.raise_for_status()
                    return _json(response)
                except (httpx.HTTPError, AnswerError) as exc:
                    failure = exc
        assert failure is not None
        raise failure

    def _fall_back(self, description: str, names: Sequence[str], why: str) -> ScenePlan:
        plan = self.fallback.read(description, names)
        plan.reader = f"{plan.reader} (fallback: {why})"
        plan.warnings.insert(0, f"the openai reader failed ({why}): read by the rules")
        return plan


def _json(response: httpx.Response) -> Any:
    """The JSON of a chat-completions reply's content (code fences and a <think> block allowed around it)."""
    try:
        content = response.json()["choices"][0]["message"]["content"]
    except (ValueError, KeyError, IndexError, TypeError) as exc:
        raise AnswerError(f"not a chat-completions reply: {response.text[:80]!r}") from exc
    if isinstance(content, list):  # content parts
        content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
    if not isinstance(content, str) or not content.strip():
        raise AnswerError("empty answer")
    text = re.sub(r"<think>.*?</think>", " ", content, flags=re.S)
    fenced = re.search(r"```(?:json)?\s*(.*?)```", text, flags=re.S)
    try:
        return json.loads(fenced.group(1) if fenced else text)
    except ValueError as exc:
        raise AnswerError(f"no JSON in the answer {text[:80]!r}") from exc


def _check(answer: Any, names: Sequence[str]) -> list[dict[str, Any]]:
    """The answer's objects, checked against ``plan_schema`` (AnswerError naming what breaks it)."""
    schema = plan_schema(names)["properties"]["objects"]["items"]
    if not isinstance(answer, dict) or set(answer) != {"objects"} or not isinstance(answer["objects"], list):
        raise AnswerError("the answer is not {\"objects\": [...]}")
    for i, item in enumerate(answer["objects"]):
        where = f"objects[{i}]"
        if not isinstance(item, dict) or set(item) != set(schema["required"]):
            raise AnswerError(f"{where} has not exactly the keys {', '.join(schema['required'])}")
        props = schema["properties"]
        if item["name"] not in props["name"]["enum"]:
            raise AnswerError(f"{where}.name {item['name']!r} is none of the objects")
        if isinstance(item["count"], bool) or not isinstance(item["count"], int) or not 1 <= item["count"] <= (
                MAX_COPIES):
            raise AnswerError(f"{where}.count must be 1 to {MAX_COPIES}")
        if item["relation"] not in props["relation"]["enum"]:
            raise AnswerError(f"{where}.relation {item['relation']!r} is none of the relations")
        on = item["on"]
        if not isinstance(on, list) or len(on) > MAX_GROUNDS or any(g not in props["name"]["enum"] for g in on):
            raise AnswerError(f"{where}.on must list at most {MAX_GROUNDS} of the objects")
    return answer["objects"]


def plan_answer(description: str, names: Sequence[str], answer: Any) -> ScenePlan:
    """The plan of a model's answer, checked as the rules' reading is: the schema, then the plan (each object placed
    once, no circle, every step's prompt read back as its relation), then ``check_plan``."""
    keys = keys_of(names)
    key_of = {" ".join(n.split()): k for n, k in zip(names, keys, strict=True)}
    reading = SceneReading()
    for item in _check(answer, names):
        figure, grounds = key_of[item["name"]], tuple(key_of[g] for g in item["on"])
        relation = item["relation"]
        wants = 2 if relation == RelationName.BETWEEN else 1
        if relation != FLOOR and not wants <= len(grounds) <= MAX_GROUNDS:
            raise AnswerError(f"{item['name']}: '{relation}' relates {'two objects' if wants == 2 else 'an object'}, "
                              f"not {len(grounds)}")
        if item["count"] > 1:
            reading.counts[figure] = item["count"]
        reading.named.append(figure)
        if relation == FLOOR:
            reading.said.append(Said(figure, RelationName.ON, "on", (), f"the {figure} on the floor", floor=True))
            continue
        name = RelationName(relation)
        words = RELATION_WORDS[name]
        clause = f"the {figure} {words} " + " and ".join(f"the {g}" for g in grounds)
        reading.said.append(Said(figure, name, words, grounds, clause, group=len(grounds) > 1 and name != "between"))
    plan = plan_relations(description, [" ".join(n.split()) for n in names], keys, reading)
    given = {said.figure: said for said in reading.said}
    for step in plan.steps:
        said = given.get(keys[step.upload])
        if said is not None and not step.floor and said.relation not in step.relation.split("+"):
            raise AnswerError(f"the step '{step.prompt}' reads as {step.relation}, not {said.relation}")
    check_plan(plan.base, [(s.name, s.on, True) for s in plan.steps])
    return plan
