"""What the service says about its own machine to a caller it does not know: nothing.

``/readyz`` and every error answer may be read without a key, so their texts pass through ``redact``: filesystem
paths (absolute, ``~``-relative, ``./``-relative) and cache folder names (``.cache/...``, the Hugging Face cache's
``models--...`` entries) become ``<path>``. Which model is missing and the command that gets it stay; where a
worker looked for it is the operator's to read in the worker's log, and a key holder's job record (``GET
/jobs/{id}``) keeps its own error as the worker wrote it. The API's own routes (``POST /align``, ...) are not paths.
Hostnames (worker names, the stores' addresses) and versions are never put in those texts.
"""

from __future__ import annotations

import re

PLACEHOLDER = "<path>"
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
