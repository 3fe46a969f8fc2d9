"""What the service says about its own machine to a client: nothing.

Every text it hands out passes through ``redact``: filesystem paths (absolute, ``~``-relative, ``./``-relative) and
cache folder names (``.cache/...``, the Hugging Face cache's ``models--...`` entries) become ``<path>``. That is
``/readyz`` and every error answer (which may be read without a key), and every job and adjustment answer (``GET
/jobs/{id}``, the job list, its events and webhooks: ``redact_model``) and ``report.json`` (``report_json``, as the
worker stores it and as it is served: each string in them, e.g. a worker's ``guide_why`` naming where it looked for
a model's weights). Which model is missing and the command that gets it stay; where a worker looked for it is the
operator's to read in the worker's log. The API's own routes (``POST /align``, ...) are not paths. Hostnames (worker
names, the stores' addresses) and versions are never put in those texts.
"""

from __future__ import annotations

import json
import re
from typing import Any, TypeVar

from pydantic import BaseModel

PLACEHOLDER = "<path>"
Model = TypeVar("Model", bound=BaseModel)
_ROUTES = "align|assemble|jobs|inspect|readyz|healthz|docs|redoc|openapi|static"
_SEGMENT = r"""[^\s'"`()\[\]{},;<>]"""
_PATHS = re.compile(
    rf"(?<![\w.~/-])(?:~[\w.-]*|\.{{1,2}})?/(?!/)(?!(?:{_ROUTES})\b){_SEGMENT}+"  # /abs, ~/home, ./rel, ../rel
    rf"|(?<![\w/])\.[\w-]+/{_SEGMENT}*"  # a dot folder: .cache/huggingface/hub
    r"|\bmodels--[\w.-]+"  # a Hugging Face cache entry
)


def redact(text: str) -> str:
    """``text`` with every filesystem path and cache folder name replaced by ``<path>``."""
    return _PATHS.sub(PLACEHOLDER, text)


def redact_json(value: Any) -> Any:
    """``value`` (parsed JSON) with ``redact`` applied to each string in it; keys and other values kept."""
    if isinstance(value, str):
        return redact(value)
    if isinstance(value, dict):
        return {key: redact_json(item) for key, item in value.items()}
    if isinstance(value, list):
        return [redact_json(item) for item in value]
    return value


def report_json(report: Any) -> bytes:
    """A job's ``report.json`` as it is stored and served: ``redact_json``, indented. The worker writes it so
    (results and saved adjustments); the download applies it again to a report an older worker wrote."""
    return json.dumps(redact_json(report), indent=2).encode()


def redact_model(model: Model) -> Model:
    """``model`` (a job's progress or error, as a worker or the service wrote it) with ``redact_json`` applied."""
    return type(model).model_validate(redact_json(model.model_dump(mode="json")))
