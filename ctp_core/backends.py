"""The guidance model backends: a spec's prefix -> its loader, and whether it gives gradients.

Kept free of torch and transformers so configuration validation (the API process imports no torch)
can refuse a run a backend cannot serve before any model loads. A loader is named ``module:function``
and imported on first use; it takes ``(spec, rest_of_spec, guidance.LoadRequest)`` and returns a
``guidance.Guide``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass

from ctp_core.errors import ModelSpecError


@dataclass(frozen=True)
class Backend:
    prefix: str
    usage: str  # what a spec of this backend looks like, for messages
    loader: str  # "module:function"
    differentiable: bool = True  # False: forward only (no image gradients, so no CLIP term to descend)

    def load_function(self) -> Callable:
        module, name = self.loader.split(":")
        return getattr(importlib.import_module(module), name)


BACKENDS: dict[str, Backend] = {b.prefix: b for b in (
    Backend("hf", "hf:REPO_OR_PATH", "ctp_core.guidance:_load_hf"),
    Backend("open_clip", "open_clip:ARCH:TAG", "ctp_core.guidance:_load_open_clip"),
    Backend("random", "random:ARCH", "ctp_core.guidance:_load_random"),
    Backend("onnx", "onnx:DIR", "ctp_core.guidance:_load_onnx", differentiable=False),
)}


def parse(spec: str) -> tuple[Backend, str]:
    """``"hf:openai/clip"`` -> (the hf backend, ``"openai/clip"``); ``ModelSpecError`` if malformed or unknown."""
    prefix, sep, rest = spec.partition(":")
    usages = ", ".join(b.usage for b in BACKENDS.values())
    if not sep or not rest:
        raise ModelSpecError(f"model spec {spec!r} must look like {usages}", field="model")
    if prefix not in BACKENDS:
        raise ModelSpecError(f"unknown model backend {prefix!r} in {spec!r}; use one of {usages}", field="model")
    return BACKENDS[prefix], rest
