"""The run options a user sets by name (job options, ``ctp assemble`` plan steps): flat names mapped onto
``AlignConfig`` fields, validated with the ranges and descriptions the engine itself enforces.

``AlignOptions`` is derived from ``AlignConfig``'s own fields; ``option_overrides`` turns a dict of options
into nested ``AlignConfig`` overrides. The HTTP schema (``service.schemas``) and the CLI share it.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model
from pydantic.fields import FieldInfo

from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.priors import PROVIDERS

# option -> where it lives in AlignConfig.
OPTION_PATHS: dict[str, tuple[str, ...]] = {
    "preset": ("preset",),
    "scale": ("scale",),
    "seed": ("seed",),
    "restarts": ("optim", "restarts"),
    "steps": ("optim", "steps"),
    "search": ("search", "enabled"),
    "candidates": ("search", "candidates"),
    "model": ("model",),
    "contact_ratio": ("contact_ratio",),
    "penetration": ("penetration",),
    "size_ratio": ("size_ratio",),
    "hparams_provider": ("hparams_provider",),
    "upright": ("upright",),
    "upright_judge": ("upright_judge",),
    "target_up": ("target_up",),
    "target_front": ("target_front",),
    "source_up": ("source_up",),
    "source_front": ("source_front",),
    "lambda_clip": ("loss", "lambda_clip"),
}
_EXTRA_DOC = {
    "preset": f"named budget ({', '.join(AlignConfig.preset_names())}); the other options override it",
    "model": "guidance model spec; must be one the service allows (CTP_MODEL, CTP_MODELS)",
    "seed": "random seed of the restarts and the samples",
    "restarts": "optimiser starts, one batch (with the search: its best distinct poses)",
    "search": "search contact poses before the optimiser (false: random starts, as the descent preset)",
    "lambda_clip": "weight of the prompt (or image) guidance; 0 is a geometry-only run (contact without "
                   "interpenetration), which needs no model and is accepted while the model is unavailable",
    "hparams_provider": "scene-prior provider for the values left unset (size_ratio, contact_ratio, penetration)",
}


def config_field(name: str) -> FieldInfo:
    """The ``AlignConfig`` field behind option ``name`` (its type, range and description)."""
    model: type[BaseModel] = AlignConfig
    *parents, leaf = OPTION_PATHS[name]
    for part in parents:
        model = model.model_fields[part].annotation
    return model.model_fields[leaf]


def _option_field(name: str) -> tuple[Any, Any]:
    info = config_field(name)
    description = _EXTRA_DOC.get(name) or info.description
    annotation = info.annotation | None
    if info.metadata:
        annotation = Annotated[annotation, *info.metadata]
    return annotation, Field(None, description=description)


AlignOptions: type[BaseModel] = create_model(
    "AlignOptions",
    __config__=ConfigDict(extra="forbid", strict=True,
                          json_schema_extra={"description": "JSON object in the `options` form field; every key "
                                             "is optional and unknown keys are refused (unknown_option)."}),
    **{name: _option_field(name) for name in OPTION_PATHS},
)


def option_overrides(options: dict[str, Any], where: str = "options") -> dict[str, Any]:
    """Validate options (AlignOptions names) and nest them as ``AlignConfig`` overrides.

    Raises ConfigError whose ``field`` is ``<where>.<name>``, code ``unknown_option`` or ``invalid_option``.
    """
    try:
        parsed = AlignOptions.model_validate(options)
    except ValidationError as exc:
        err = exc.errors()[0]
        name = ".".join(str(p) for p in err["loc"])
        if err["type"] == "extra_forbidden":
            raise ConfigError(f"unknown option {name!r}; known: {', '.join(OPTION_PATHS)}",
                              code="unknown_option", field=f"{where}.{name}") from None
        raise ConfigError(f"{name}: {err['msg']}", field=f"{where}.{name}") from None
    given = parsed.model_dump(exclude_none=True)
    if given.get("hparams_provider", PROVIDERS[0]) not in PROVIDERS:
        raise ConfigError(f"unknown priors provider {given['hparams_provider']!r}; choose one of "
                          f"{', '.join(PROVIDERS)}", field=f"{where}.hparams_provider")
    return nest(given)


def nest(values: dict[str, Any]) -> dict[str, Any]:
    """Option values by name as nested ``AlignConfig`` overrides (``{"restarts": 2}`` -> ``{"optim": {"restarts":
    2}}``); not validated here (``option_overrides`` validates, ``AlignConfig`` always does)."""
    overrides: dict[str, Any] = {}
    for name, value in values.items():
        *parents, leaf = OPTION_PATHS[name]
        node = overrides
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return overrides


def option_of(config_field: str | None) -> str | None:
    for name, path in OPTION_PATHS.items():
        if config_field == ".".join(path):
            return f"options.{name}"
    return f"options.{config_field}" if config_field else "options"
