"""The guidance model backends: the spec prefixes, what a spec of each looks like, whether it gives gradients.

Kept free of torch and transformers so configuration validation (the API process imports no torch)
can refuse a run a backend cannot serve before any model loads. Each backend's loader (which needs torch)
is ``loaders.LOADERS[prefix]``; this module does not import it.
"""

from __future__ import annotations

from dataclasses import dataclass

from ctp_core.errors import ModelSpecError


@dataclass(frozen=True)
class Backend:
    prefix: str
    usage: str  # what a spec of this backend looks like, for messages
    differentiable: bool = True  # False: forward only (no image gradients, so no CLIP term to descend)


BACKENDS: dict[str, Backend] = {b.prefix: b for b in (
    Backend("hf", "hf:REPO_OR_PATH"),
    Backend("open_clip", "open_clip:ARCH:TAG"),
    Backend("random", "random:ARCH"),
    Backend("onnx", "onnx:DIR", differentiable=False),
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
