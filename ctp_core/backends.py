"""The guidance model backends: a spec's prefix -> its loader, and whether it gives gradients.

Kept free of torch and transformers so configuration validation (the API process imports no torch)
can refuse a run a backend cannot serve before any model loads. A backend's loader (in ``guide_loaders``,
which needs torch) is imported on first use; it takes ``(spec, rest_of_spec, guidance.LoadRequest)`` and
returns a ``guidance.Guide``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ctp_core.errors import ModelSpecError


@dataclass(frozen=True)
class Backend:
    prefix: str
    usage: str  # what a spec of this backend looks like, for messages
    differentiable: bool = True  # False: forward only (no image gradients, so no CLIP term to descend)

    def load_function(self) -> Callable:
        """This backend's loader, ``guide_loaders.load_<prefix>``; imported here, on first use, as it needs torch."""
        from ctp_core import guide_loaders

        return {"hf": guide_loaders.load_hf, "open_clip": guide_loaders.load_open_clip,
                "random": guide_loaders.load_random, "onnx": guide_loaders.load_onnx}[self.prefix]


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
