"""The HTTP contract's bodies (they generate ``openapi.yaml``) and ``build_config``: a job's options
(``ctp_core.config.options``, the vocabulary the CLI's plans share) merged into their preset, with the models this
service allows; an option left out takes the preset's value.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, Field, create_model

from ctp_core.config import AUTO, DEFAULT_MODEL, AlignConfig
from ctp_core.config.options import AlignOptions, option_of, option_overrides
from ctp_core.errors import ConfigError
from ctp_core.guide.selection import asks_for_guide
from ctp_core.reading.counts import CHOICES, MAX_COPIES
from service.jobs import Alternative, JobError, JobRecord, Progress, SavedAdjustment, Status
from service.redact import redact, redact_model
from service.settings import QUEUE_NAME
from service.webhooks import Event, Webhook


def build_config(options: dict[str, Any], *, default_model: str, allowed_models: list[str],
                 image: bool = False) -> AlignConfig:
    """Validate a client's options and merge them into their preset; raises ConfigError whose
    ``field`` is ``options.<name>``, code ``unknown_option`` or ``invalid_option``. A job under ``auto`` that
    asks for guidance itself (``image``: a reference picture; ``selection.asks_for_guide``) gets the default
    model, so that it is refused up front (503 ``model_unavailable``) where no worker has it."""
    overrides = option_overrides(options)
    model = overrides.get("model", default_model)
    if model == AUTO and asks_for_guide(options, image):
        model = DEFAULT_MODEL
    if model not in allowed_models:
        raise ConfigError(f"model {model!r} is not served here; choose one of {', '.join(allowed_models)}",
                          field="options.model")
    overrides["model"] = model  # where it runs (device, threads) is the worker's setting
    preset = overrides.pop("preset", "default")
    try:
        return AlignConfig.from_preset(preset, **overrides)
    except ConfigError as exc:
        raise ConfigError(exc.message, field=option_of(exc.field)) from None


# The options field of a submit: the engine's options and the service's own, where the job runs (for the schema;
# service.forms.job_options splits them, build_config checks the engine's).
JobOptions: type[BaseModel] = create_model(
    "JobOptions", __base__=AlignOptions,
    queue=(str | None, Field(None, pattern=QUEUE_NAME, description="the named queue the job goes to (default: "
                             "the deployment's, CTP_DEFAULT_QUEUE); 422 queue_not_served when no worker serves it")),
    count=(int | None, Field(None, description=f"POST /align: copies of the source to place, 1 to {MAX_COPIES} (422 "
                             "count_out_of_range beyond); default: the prompt's number (\"three apples\"), else 1; "
                             "over 1, result.glb has one node per copy (SOURCE_NAME_1 ...) and the report lists each")),
    arrangement=(Literal[CHOICES] | None, Field(None, description="POST /align with several copies: scatter, around "
                                                "(facing the target), row, stack, or auto (default: the prompt's "
                                                "\"around\", \"in a row\", \"stack of\", else scatter)")),
)


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
    downloads: Literal["stream", "redirect"] = Field(
        description="how result, report and preview answer once the job succeeded: stream (200 with "
        "the file, from the API) or redirect (307 to a short-lived URL of the object store, CTP_S3_PRESIGN_S; "
        "follow it without the Authorization header, which the URL does not need)")


def links(job_id: str, downloads: Literal["stream", "redirect"]) -> Links:
    base = f"/jobs/{job_id}"
    return Links(self=base, events=f"{base}/events", result=f"{base}/result.glb", report=f"{base}/report.json",
                 preview=f"{base}/preview.png", cancel=base, downloads=downloads)


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
    attempts: int = Field(0, description="runs of it that workers started (a run handed back by a stopping worker is "
                          "not counted): a job whose worker was lost is queued again once, so at most 2")
    prompt: str | None = Field(None, description="the text prompt (null for image-guided jobs without one)")
    image_guided: bool = Field(description="guided by a reference image instead of the text")
    kind: Literal["align", "assemble"] = Field(description="align: one source placed (POST /align); assemble: a "
                                               "scene of several objects (POST /assemble, POST /scenes)")
    description: str | None = Field(None, description="an assembly: the scene in one sentence (POST /scenes's "
                                    "prompt, POST /assemble's description, else its steps' prompts joined); "
                                    "null for an alignment")
    webhook: Webhook | None = Field(None, description="the job's webhook and how its deliveries went; null "
                                    "when it was submitted without one")
    queue: str = Field(description="the named queue it was sent to (option queue)")
    target_job: str | None = Field(None, description="the job whose result scene is this one's target (POST /align "
                                   "with target_job: an object added to that scene); null otherwise")
    stages: int = Field(1, description="objects this job places: 1 for POST /align, the plan's steps for POST "
                        "/assemble (the scene holds one more: the base, which stays put)")
    count: int = Field(1, description="copies of the source this alignment places (options.count, or the prompt's "
                       "number)")
    arrangement: str | None = Field(None, description="how the copies stand together (scatter, around, row, "
                                    "stack); null for one copy")
    alternatives: list[Alternative] = Field(default_factory=list, description="a succeeded alignment's best "
                                            "distinct placements, the answer first: each one's GLB at "
                                            "result.glb?alternative=k and a view in alternatives.png (image k "
                                            "at x = k x its width)")
    adjusted: SavedAdjustment | None = Field(None, description="a saved adjustment (POST /jobs/{id}/adjust with save), "
                                      "the latest: result.glb and report.json are the adjusted scene, original.glb "
                                      "the run's own; null until one is saved")
    guide: str | None = Field(None, description="what guides the placement, chosen by the worker when it took the "
                              "job: a model spec, or none (the geometry and the prompt's relation: options.model "
                              "auto without the default model's weights, or lambda_clip 0); null while queued")
    guide_why: str | None = Field(None, description="why that guide; null while queued")
    links: Links

    @classmethod
    def of(cls, r: JobRecord) -> JobOut:
        """The job as every answer, event and webhook gives it: what the service and its workers wrote in it
        (progress, error, guide) without the machine's paths (``service.redact``)."""
        return cls(id=r.id, status=r.status, progress=redact_model(r.progress), created_at=r.created_at,
                   started_at=r.started_at, finished_at=r.finished_at, error=r.error and redact_model(r.error),
                   cancel_requested=r.cancel_requested, attempts=r.attempts, prompt=r.prompt, image_guided=r.has_image,
                   kind=r.kind, description=r.description,
                   webhook=r.webhook, queue=r.queue, target_job=r.target_job, stages=r.stage_count,
                   count=r.count, arrangement=r.arrangement,
                   alternatives=r.alternatives, adjusted=r.adjusted, guide=r.guide and redact(r.guide),
                   guide_why=r.guide_why and redact(r.guide_why), links=links(r.id, r.downloads))


class WebhookPayload(BaseModel):
    """The body of a webhook delivery (Standard Webhooks' shape)."""

    type: Event = Field(description="the event: start (a worker took the job), progress, completed (succeeded, "
                        "failed or canceled)")
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
        description="ready: a live worker of the default queue can run the default model; restarting: no worker of "
        "the default queue is live now, but one that could was seen within the grace (CTP_WORKER_GRACE_S), e.g. "
        "while it is restarted; jobs are accepted and wait in the queue until a worker is back")
    redis: bool = Field(description="Redis answered")
    workers: int = Field(description="workers, of any queue, that sent a heartbeat within the lease "
                         "(CTP_LEASE_S); none of them serves the default queue while restarting")
    models: list[str] = Field(description="the models jobs on the default queue are accepted for: those at least "
                              "one live worker of it can run now, or while restarting those the workers seen "
                              "within the grace could run (the default among them, or the answer is 503)")
    queues: dict[str, list[str]] = Field(
        default_factory=dict, description="every named queue jobs are accepted for (option queue) -> the models "
        "they may need there: those its live workers can run, or while none is live those its workers seen "
        "within the grace could run")
    since_s: float | None = Field(None, description="restarting: seconds since a worker was last seen (the "
                                  "answer turns 503 no_worker once this passes the grace); null when ready")
    guide: str = Field(description="what guides jobs with default options: CTP_MODEL when it names a model; with auto "
                       "the default CLIP model where a worker of the default queue has its weights, else none (the "
                       "geometry and the prompt's relation place the source)")
    why: str = Field(description="why that guide")
    get_model: str | None = Field(None, description="guide none under auto: the command that puts the default "
                                  "model's weights on the workers (then each next job uses it)")
