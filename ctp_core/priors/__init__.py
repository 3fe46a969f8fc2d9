"""Scene priors: size ratio, penetration and contact ratio for a (target, source, prompt) triple.

The hyperparameter step of the method (../shared/docs/method.md) behind one interface: ``get_provider("rules")``
(default: lexicon + prompt cues, deterministic, offline) or ``get_provider("openai")`` (any
OpenAI-compatible chat endpoint, falling back to the rules on any failure). ``resolve_priors`` is what
``align`` calls: the provider's estimate, overridden by whatever the caller set explicitly.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from ctp_core.errors import ConfigError
from ctp_core.priors.prior import PriorProvider, ScenePrior, clamp_size, to_report
from ctp_core.priors.rules import RulesProvider
from ctp_core.reading import lexicon, places

if TYPE_CHECKING:  # loaded on first use: the rules need no HTTP client (httpx) or settings reader
    from ctp_core.priors.openai import OpenAIProvider, PriorSettings

__all__ = ["PROVIDERS", "OpenAIProvider", "PriorProvider", "PriorSettings", "RulesProvider", "ScenePrior",
           "get_provider", "mesh_size_ratio", "resolve_priors", "to_report"]

PROVIDERS = ("rules", "openai")
EXPLICIT_SIZE_RANGE = (0.01, 100.0)  # what a caller may ask for (AlignConfig.size_ratio)
UNITS_M = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}  # file units a mesh may plausibly be in
PLAUSIBLE_FACTOR = 3.0  # a mesh "looks real" when within this factor of its object's typical size
AGREE_FACTOR = 2.5  # ... and the two meshes' ratio within this factor of the typical sizes' ratio


def __getattr__(name: str) -> Any:
    """``OpenAIProvider`` and ``PriorSettings``, imported when first asked for."""
    if name in ("OpenAIProvider", "PriorSettings"):
        from ctp_core.priors import openai

        return getattr(openai, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def get_provider(name: str = "rules", settings: PriorSettings | None = None) -> PriorProvider:
    """A provider by name; ``settings`` (default: from CTP_LLM_* env) configure "openai"."""
    if name == "rules":
        return RulesProvider()
    if name == "openai":
        from ctp_core.priors.openai import OpenAIProvider, PriorSettings

        return OpenAIProvider(settings or PriorSettings())
    raise ConfigError(f"unknown priors provider {name!r}; choose one of {', '.join(PROVIDERS)}",
                      field="hparams_provider")


def mesh_size_ratio(target_name: str, source_name: str, target_extent: float,
                    source_extent: float) -> tuple[float, str] | None:
    """The file-unit size ratio, when both meshes look modelled at real size in one common unit.

    Files are often in arbitrary units, and in the scale-mode benchmark deliberately mis-scaled, so
    the files' ratio is trusted only when both objects are known, each lands within PLAUSIBLE_FACTOR
    of its typical size read in one of m/cm/mm/in, and their ratio is within AGREE_FACTOR of the
    typical sizes' ratio: then the meshes refine the estimate (a stylised church's small cross) rather
    than replace it with an accident of scale. Returns (ratio, why) or None.
    """
    target, source = lexicon.lookup(target_name), lexicon.lookup(source_name)
    if target is None or source is None or min(target_extent, source_extent) <= 0:
        return None
    ratio = source_extent / target_extent
    if not 1 / AGREE_FACTOR <= ratio / (source.size_m / target.size_m) <= AGREE_FACTOR:
        return None
    for unit, metres in UNITS_M.items():
        if all(1 / PLAUSIBLE_FACTOR <= extent * metres / match.size_m <= PLAUSIBLE_FACTOR
               for extent, match in ((target_extent, target), (source_extent, source))):
            return ratio, (f"the mesh extents set the size ratio to {clamp_size(ratio):.3g} (both plausible in {unit}: "
                           f"{target_extent * metres:.3g} m and {source_extent * metres:.3g} m)")
    return None


def resolve_priors(
    provider: PriorProvider,
    target_name: str,
    source_name: str,
    prompt: str,
    *,
    size_ratio: float | None = None,
    penetration: bool | None = None,
    contact_ratio: float | None = None,
    target_extent: float | None = None,
    source_extent: float | None = None,
) -> ScenePrior:
    """The provider's estimate with the caller's explicit values on top.

    Explicit values always win and are kept as given (a size ratio in [0.01, 100], a contact ratio in
    [0, 1]; ConfigError otherwise); ``provider`` lists them. Mesh extents (longest sides, file units)
    replace the estimated size ratio only when ``mesh_size_ratio`` finds them plausible. The provider
    is not asked when all three are explicit.
    """
    _check_explicit(size_ratio, contact_ratio)
    explicit = [k for k, v in (("size_ratio", size_ratio), ("penetration", penetration),
                               ("contact_ratio", contact_ratio)) if v is not None]
    if len(explicit) == 3:
        return ScenePrior(float(size_ratio), bool(penetration), float(contact_ratio), "explicit",
                          "all three values given by the caller")
    prior = provider.estimate(target_name, source_name, prompt)
    reasons = [prior.reason]
    if size_ratio is None and target_extent is not None and source_extent is not None:
        from_mesh = mesh_size_ratio(target_name, source_name, target_extent, source_extent)
        if from_mesh is not None:
            size_ratio = clamp_size(from_mesh[0])
            reasons.append(from_mesh[1])
    if explicit:
        reasons.append("explicit: " + ", ".join(explicit))
    return ScenePrior(
        size_ratio=float(prior.size_ratio if size_ratio is None else size_ratio),
        penetration=bool(prior.penetration if penetration is None else penetration),
        contact_ratio=float(prior.contact_ratio if contact_ratio is None else contact_ratio),
        provider=prior.provider + ("; explicit: " + ", ".join(explicit) if explicit else ""),
        reason="; ".join(reasons),
        reading=None if prior.reading is None else replace(prior.reading, place=places.read_place(prompt)),
    )


def _check_explicit(size_ratio: float | None, contact_ratio: float | None) -> None:
    lo, hi = EXPLICIT_SIZE_RANGE
    if size_ratio is not None and not (math.isfinite(size_ratio) and lo <= size_ratio <= hi):
        raise ConfigError(f"size_ratio must be in [{lo:g}, {hi:g}], got {size_ratio!r}", field="size_ratio")
    if contact_ratio is not None and not (math.isfinite(contact_ratio) and 0.0 <= contact_ratio <= 1.0):
        raise ConfigError(f"contact_ratio must be in [0, 1], got {contact_ratio!r}", field="contact_ratio")
