"""The HTTP contract's bodies (they generate ``openapi.yaml``) and the mapping of job options onto
``AlignConfig``.

``AlignOptions`` is derived from ``AlignConfig``'s own fields, so the ranges and descriptions a client
reads in the schema are the ones the engine enforces; an option left out takes the preset's value.
"""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model

from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.priors import PROVIDERS
from service.jobs import JobError, JobRecord, Progress, Status

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


def _option_field(name: str, path: tuple[str, ...]) -> tuple[Any, Any]:
    model: type[BaseModel] = AlignConfig
    for part in path[:-1]:
        model = model.model_fields[part].annotation
    info = model.model_fields[path[-1]]
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
    **{name: _option_field(name, path) for name, path in OPTION_PATHS.items()},
)


def build_config(options: dict[str, Any], *, default_model: str, allowed_models: list[str]) -> AlignConfig:
    """Validate a client's options and merge them into their preset; raises ConfigError whose
    ``field`` is ``options.<name>``, code ``unknown_option`` or ``invalid_option``."""
    overrides = option_overrides(options)
    model = overrides.get("model", default_model)
    if model not in allowed_models:
        raise ConfigError(f"model {model!r} is not served here; choose one of {', '.join(allowed_models)}",
                          field="options.model")
    overrides["model"] = model  # where it runs (device, threads) is the worker's setting
    preset = overrides.pop("preset", "default")
    try:
        return AlignConfig.from_preset(preset, **overrides)
    except ConfigError as exc:
        raise ConfigError(exc.message, field=_option_of(exc.field)) from None


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
        raise ConfigError(f"unknown hparams provider {given['hparams_provider']!r}; choose one of "
                          f"{', '.join(PROVIDERS)}", field=f"{where}.hparams_provider")
    overrides: dict[str, Any] = {}
    for name, value in given.items():
        *parents, leaf = OPTION_PATHS[name]
        node = overrides
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return overrides


def _option_of(config_field: str | None) -> str | None:
    for name, path in OPTION_PATHS.items():
        if config_field == ".".join(path):
            return f"options.{name}"
    return f"options.{config_field}" if config_field else "options"


class ErrorBody(BaseModel):
    """Every 4xx/5xx answer of this API."""

    error: JobError


class Links(BaseModel):
    """Where to go next; relative to the API root."""

    self: str = Field(description="this job")
    events: str = Field(description="server-sent progress events until the job ends")
    result: str = Field(description="the scene as GLB (target untouched, source placed); 409 until succeeded")
    report: str = Field(description="transform, objective, priors, timings as JSON; 409 until succeeded")
    preview: str = Field(description="PNG strip of the final scene's views; 409 until succeeded")
    cancel: str = Field(description="DELETE this to cancel")


def links(job_id: str) -> Links:
    base = f"/jobs/{job_id}"
    return Links(self=base, events=f"{base}/events", result=f"{base}/result.glb", report=f"{base}/report.json",
                 preview=f"{base}/preview.png", cancel=base)


class Accepted(BaseModel):
    """The answer to a valid submission: the job is queued."""

    id: str = Field(description="job id")
    status: Status = Field(description="always queued")
    links: Links


class JobOut(BaseModel):
    """A job as clients see it."""

    id: str = Field(description="job id")
    status: Status = Field(description="queued, running, succeeded, failed or canceled")
    progress: Progress
    created_at: datetime = Field(description="when the API accepted it (UTC)")
    started_at: datetime | None = Field(None, description="when a worker picked it up (UTC)")
    finished_at: datetime | None = Field(None, description="when it ended (UTC)")
    error: JobError | None = Field(None, description="why it failed or was canceled")
    cancel_requested: bool = Field(description="a DELETE was received; a running job stops at its next step")
    prompt: str | None = Field(None, description="the text prompt (null for image-guided jobs without one)")
    image_guided: bool = Field(description="guided by a reference image instead of the text")
    links: Links

    @classmethod
    def of(cls, r: JobRecord) -> JobOut:
        return cls(id=r.id, status=r.status, progress=r.progress, created_at=r.created_at,
                   started_at=r.started_at, finished_at=r.finished_at, error=r.error,
                   cancel_requested=r.cancel_requested, prompt=r.prompt, image_guided=r.has_image,
                   links=links(r.id))


class JobList(BaseModel):
    """A page of the caller's jobs, newest first."""

    jobs: list[JobOut] = Field(description="newest first")
    total: int = Field(description="the caller's jobs that have not expired")
    offset: int = Field(description="jobs skipped before this page")
    limit: int = Field(description="page size asked for")
    next: str | None = Field(None, description="the next page (relative URL); null on the last page")


class Health(BaseModel):
    status: str = Field(description="ok")


class Ready(BaseModel):
    status: str = Field(description="ready")
    redis: bool = Field(description="Redis answered")
    workers: int = Field(description="workers that sent a heartbeat within the lease (CTP_LEASE_S)")
    models: list[str] = Field(description="the models at least one live worker can run now (the default among "
                              "them, or the answer is 503)")
