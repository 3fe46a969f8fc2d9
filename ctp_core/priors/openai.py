"""Scene priors from a language model behind any OpenAI-compatible chat-completions endpoint.

vLLM, llama.cpp's server, Ollama and hosted APIs all speak ``POST {base_url}/chat/completions``. As in
the paper, each value is its own question answered as one JSON value; answers are parsed leniently
(code fences, surrounding prose, ``{"size_ratio": 0.3}`` or a bare ``0.3``, "yes"/"no") and clamped.
Any failure (no endpoint configured, connection refused, timeout, HTTP error, an answer that is not a
value) falls back to the rules for all three values, and ``provider`` says why: a run never stops for a
flaky endpoint.
"""

from __future__ import annotations

import json
import math
import re
from typing import TYPE_CHECKING

from pydantic import SecretStr
from pydantic_settings import BaseSettings, SettingsConfigDict

from ctp_core.priors.prior import ScenePrior, clamp_contact, clamp_size
from ctp_core.priors.rules import RulesProvider

if TYPE_CHECKING:  # imported where an endpoint is asked: a run with none (the default) never loads it
    import httpx


class PriorSettings(BaseSettings):
    """Endpoint settings; from the environment (CTP_LLM_BASE_URL, CTP_LLM_MODEL, CTP_LLM_API_KEY, ...)."""

    model_config = SettingsConfigDict(env_prefix="CTP_LLM_", extra="ignore")

    base_url: str | None = None  # e.g. http://127.0.0.1:8000/v1 (vLLM), http://127.0.0.1:11434/v1 (Ollama)
    model: str | None = None  # sent when set; llama.cpp ignores it, vLLM and Ollama need the served name
    api_key: SecretStr | None = None  # sent as a Bearer token when set
    timeout_s: float = 20.0  # per request
    retries: int = 1  # further attempts per question after a failure


SYSTEM = ("You estimate physical properties of 3D object arrangements. "
          "Answer with a single JSON value and nothing else.")

QUESTIONS = {
    "size_ratio": (
        "Scene: \"{prompt}\". Object A is a {source}; object B is a {target}. Estimate the ratio of A's "
        "bounding-box size (its longest side) to B's in this scene, a number between 0.01 and 100. "
        "Answer with one JSON number, e.g. 0.25."),
    "penetration": (
        "Scene: \"{prompt}\". Object A is a {source}; object B is a {target}. Does this arrangement require "
        "one solid to pass into the other, as a knife cutting an apple or an arrow stuck in a target do "
        "(going into a cup, a box or a hat does not count)? Answer with one JSON boolean: true or false."),
    "contact_ratio": (
        "Scene: \"{prompt}\". Object A is a {source}; object B is a {target}. What fraction of A's surface "
        "touches B? 0 for objects that do not touch, about 0.1 for a cup standing on a table, about 0.5 for "
        "a glove on a hand. Answer with one JSON number between 0 and 1."),
}


class AnswerError(ValueError):
    """The model's reply does not contain a usable value."""


class OpenAIProvider:
    """Asks the three questions; on any failure answers with the rules and says so."""

    name = "openai"

    def __init__(self, settings: PriorSettings, fallback: RulesProvider | None = None):
        self.settings = settings
        self.fallback = fallback or RulesProvider()

    def estimate(self, target_name: str, source_name: str, prompt: str) -> ScenePrior:
        if not self.settings.base_url:
            return self._fall_back(target_name, source_name, prompt, "no endpoint (CTP_LLM_BASE_URL unset)")
        import httpx

        names = {"target": _readable(target_name), "source": _readable(source_name), "prompt": prompt}
        answers = {}
        try:
            with httpx.Client(base_url=self.settings.base_url.rstrip("/") + "/", timeout=self.settings.timeout_s,
                              headers=self._headers()) as client:
                for key, question in QUESTIONS.items():
                    answers[key] = self._ask(client, key, question.format(**names))
        except (httpx.HTTPError, AnswerError) as exc:
            why = f"{type(exc).__name__}: {exc}".splitlines()[0][:200]
            return self._fall_back(target_name, source_name, prompt, why)
        rules = self.fallback.estimate(target_name, source_name, prompt)  # the relation is read by the rules
        return ScenePrior(size_ratio=clamp_size(answers["size_ratio"]), penetration=answers["penetration"],
                          contact_ratio=clamp_contact(answers["contact_ratio"]), provider=self.name,
                          reason=f"answered by {self.settings.model or 'the endpoint default model'}",
                          reading=rules.reading)

    def _headers(self) -> dict[str, str]:
        key = self.settings.api_key
        return {"Authorization": f"Bearer {key.get_secret_value()}"} if key else {}

    def _ask(self, client: httpx.Client, key: str, question: str):
        """One question, retried on any failure; the last failure propagates."""
        body = {"messages": [{"role": "system", "content": SYSTEM}, {"role": "user", "content": question}],
                "temperature": 0, "max_tokens": 256}
        if self.settings.model:
            body["model"] = self.settings.model
        import httpx

        failure: Exception | None = None
        for _ in range(self.settings.retries + 1):
            try:
                response = client.post("chat/completions", json=body)
                response.raise_for_status()
                return parse_answer(_content(response), key)
            except (httpx.HTTPError, AnswerError) as exc:
                failure = exc
        raise failure

    def _fall_back(self, target_name: str, source_name: str, prompt: str, why: str) -> ScenePrior:
        prior = self.fallback.estimate(target_name, source_name, prompt)
        return ScenePrior(prior.size_ratio, prior.penetration, prior.contact_ratio,
                          provider=f"{prior.provider} (fallback: {why})",
                          reason=f"openai provider failed ({why}); {prior.reason}",
                          reading=prior.reading)


def _readable(name: str) -> str:
    """"coffee_cup" -> "coffee cup": file-style names read better to a language model."""
    return re.sub(r"[_\-]+", " ", name).strip() or name


def _content(response: httpx.Response) -> str:
    try:
        message = response.json()["choices"][0]["message"]
    except (ValueError, KeyError, IndexError, TypeError) as exc:
        raise AnswerError(f"not a chat-completions reply: {response.text[:80]!r}") from exc
    content = message.get("content") if isinstance(message, dict) else None
    if isinstance(content, list):  # content parts
        content = "".join(p.get("text", "") for p in content if isinstance(p, dict))
    if not isinstance(content, str) or not content.strip():
        raise AnswerError("empty answer")
    return content


_KEYS = {"size_ratio": ("size_ratio", "ratio", "size", "value", "answer"),
         "penetration": ("penetration", "penetrates", "requires_penetration", "value", "answer"),
         "contact_ratio": ("contact_ratio", "contact", "ratio", "fraction", "value", "answer")}
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def parse_answer(text: str, key: str) -> float | bool:
    """The value of one answer: a bool for "penetration", a float otherwise (not yet clamped).

    Accepts a bare JSON value, an object holding it, either inside code fences or prose, after a
    model's <think> block; "yes"/"no" and "30%" too. Raises AnswerError when nothing fits.
    """
    text = re.sub(r"<think>.*?</think>", " ", text, flags=re.S)
    fenced = re.search(r"```(?:json)?\s*(.*?)```", text, flags=re.S)
    text = (fenced.group(1) if fenced else text).strip()
    candidates: list = []
    try:
        candidates.append(json.loads(text))
    except ValueError:
        candidates += [_loads(m) for m in re.findall(r"\{.*?\}", text, flags=re.S)]
        candidates += re.findall(r"\b(?:true|false|yes|no)\b", text, flags=re.I)
        candidates += re.findall(_NUMBER + r"\s*%?", text)
    for value in candidates:
        value = _unwrap(value, key)
        converted = _as_bool(value) if key == "penetration" else _as_number(value)
        if converted is not None and not (key == "size_ratio" and converted <= 0):
            return converted
    raise AnswerError(f"no {key} in the answer {text[:80]!r}")


def _loads(text: str):
    try:
        return json.loads(text)
    except ValueError:
        return None


def _unwrap(value, key: str):
    """{"size_ratio": 0.3} -> 0.3; [0.3] -> 0.3; an object with one value -> that value."""
    if isinstance(value, list) and len(value) == 1:
        return _unwrap(value[0], key)
    if isinstance(value, dict):
        for name in _KEYS[key]:
            if name in value:
                return _unwrap(value[name], key)
        if len(value) == 1:
            return _unwrap(next(iter(value.values())), key)
    return value


def _as_bool(value) -> bool | None:
    if isinstance(value, bool):
        return value
    if isinstance(value, (int, float)) and value in (0, 1):
        return bool(value)
    if isinstance(value, str):
        return {"true": True, "yes": True, "false": False, "no": False}.get(value.strip().lower().rstrip("."))
    return None


def _as_number(value) -> float | None:
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, (int, float)):
        number = float(value)
    elif isinstance(value, str):
        m = re.fullmatch(r"\s*(" + _NUMBER + r")\s*(%?)\s*", value)
        if not m:
            return None
        number = float(m.group(1)) / (100.0 if m.group(2) else 1.0)
    else:
        return None
    return number if math.isfinite(number) else None
