"""The HTTP contract's bodies (they generate ``openapi.yaml``) and ``build_config``: a job's options
(``ctp_core.options``, the vocabulary the CLI's plans share) merged into their preset, with the models this
service allows; an option left out takes the preset's value.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, Field

from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.options import option_of, option_overrides
from service.jobs import JobError, JobRecord, Progress, Status
from service.webhooks import Webhook


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
        raise ConfigError(exc.message, field=option_of(exc.field)) from None


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
    status: Status = Field(description="queued (or running, after a `Prefer: wait` that ran out)")
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
    webhook: Webhook | None = Field(None, description="the job's webhook and how its deliveries went; null "
                                    "when it was submitted without one")
    links: Links

    @classmethod
    def of(cls, r: JobRecord) -> JobOut:
        return cls(id=r.id, status=r.status, progress=r.progress, created_at=r.created_at,
                   started_at=r.started_at, finished_at=r.finished_at, error=r.error,
                   cancel_requested=r.cancel_requested, prompt=r.prompt, image_guided=r.has_image,
                   webhook=r.webhook, links=links(r.id))


class WebhookPayload(BaseModel):
    """The body of a webhook delivery (Standard Webhooks' shape)."""

    type: Literal["start", "progress", "completed"] = Field(description="the event: start (a worker took the "
                                                             "job), progress, completed (succeeded, failed or "
                                                             "canceled)")
    timestamp: datetime = Field(description="when the event happened (UTC)")
    data: JobOut = Field(description="the job as GET /jobs/{id} showed it right after the event")


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
    status: Literal["ready", "restarting"] = Field(
        description="ready: a live worker can run the default model; restarting: no worker is live now, but one "
        "that could was seen within the grace (CTP_WORKER_GRACE_S), e.g. while it is restarted; jobs are "
        "accepted and wait in the queue until a worker is back")
    redis: bool = Field(description="Redis answered")
    workers: int = Field(description="workers that sent a heartbeat within the lease (CTP_LEASE_S); 0 while "
                         "restarting")
    models: list[str] = Field(description="the models jobs are accepted for: those at least one live worker can "
                              "run now, or while restarting those the workers seen within the grace could run "
                              "(the default among them, or the answer is 503)")
    since_s: float | None = Field(None, description="restarting: seconds since a worker was last seen (the "
                                  "answer turns 503 no_worker once this passes the grace); null when ready")
