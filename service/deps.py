"""Request dependencies shared by the routers: who is calling, the caller's own job, and queueing a job.

They read what ``create_app`` put on ``app.state``: ``settings``, ``jobs`` (the job store), ``aredis``
(the event loop's Redis client) and ``key_digests``.
"""

from __future__ import annotations

import hashlib
import hmac
import re
from collections.abc import Sequence

from fastapi import Request
from fastapi.concurrency import run_in_threadpool

from ctp_core.config import AUTO, DEFAULT_MODEL, AlignConfig
from service.errors import ApiError
from service.jobs import JobError, JobRecord, Jobs, TooManyJobs
from service.workers import serving

_JOB_ID = re.compile(r"[0-9a-f]{32}")


def digest(key: str) -> str:
    """What the service stores of an API key: never the key itself."""
    return hashlib.sha256(key.encode()).hexdigest()[:32]


async def owner(request: Request) -> str:
    """The caller's identity: a digest of its API key, or "public" when the service has none."""
    key_digests = request.app.state.key_digests
    if not key_digests:
        return "public"
    scheme, _, token = request.headers.get("authorization", "").partition(" ")
    given = digest(token.strip()) if scheme.lower() == "bearer" and token.strip() else ""
    if not any(hmac.compare_digest(given, d) for d in key_digests):
        raise ApiError(401, "unauthorized", "send Authorization: Bearer <API key>",
                       headers={"WWW-Authenticate": "Bearer"})
    return given


async def own_job(request: Request, job_id: str, who: str) -> JobRecord:
    """The caller's job, read on the event loop (the hot path: clients poll it); 404 for anyone else's."""
    state = request.app.state
    record = await state.jobs.get_async(state.aredis, job_id) if _JOB_ID.fullmatch(job_id) else None
    if record is None or record.owner != who:
        raise ApiError(404, "job_not_found", f"no job {job_id!r}")
    return record


async def enqueue(request: Request, record: JobRecord, blobs: dict[str, bytes],
                  configs: Sequence[AlignConfig], claim: tuple[str, str] | None = None) -> None:
    """Queue a validated job (``POST /align`` and ``POST /assemble``, through ``service.submit``) on its named
    queue: 503 when no worker can run it and 422 ``queue_not_served`` when no worker serves its queue (refused
    now rather than accepted and failed later; a worker being restarted counts, ``Jobs.unavailable``), 429 over
    the key's active-job limit.

    ``configs`` are what the job runs: an assembly's every stage (each with its own options), so one guided
    step makes the job need the model however geometry-only the assembly's options are. ``claim``: the request's
    ``Idempotency-Key`` claim, kept as long as the job by the transaction that queues it (``Jobs.submit``)."""
    settings, jobs = request.app.state.settings, request.app.state.jobs
    await check_workers(request, {c.model for c in configs if c.uses_model}, record.queue)
    try:
        await run_in_threadpool(jobs.submit, record, blobs, settings.max_active_jobs, claim)
    except TooManyJobs as exc:
        raise ApiError(429, "too_many_jobs", str(exc), headers={"Retry-After": str(exc.retry_after_s)}) from None


async def check_workers(request: Request, models: set[str], queue: str) -> None:
    """Refuse work no worker can run now: 503 (no worker, the model unavailable) or 422 ``queue_not_served``;
    ``models`` empty: any worker of ``queue`` will do (``Jobs.unavailable``)."""
    unavailable = await run_in_threadpool(_unavailable, request.app.state.jobs, models, queue)
    if unavailable is not None:
        status = 422 if unavailable.code == "queue_not_served" else 503  # the request's to change, not a wait
        message, auto = unavailable.message, request.app.state.settings.model == AUTO
        if unavailable.code == "model_unavailable" and auto and DEFAULT_MODEL in models:
            message = (f"this job asks for guidance itself (a reference image, lambda_clip or upright_judge), which "
                       f"needs the default model under CTP_MODEL auto (jobs with default options run without a "
                       f"guide): {message}")
        raise ApiError(status, unavailable.code, message, unavailable.field)


def _unavailable(jobs: Jobs, models: set[str], queue: str) -> JobError | None:
    """The first reason a job on ``queue`` needing ``models`` cannot run (the workers read once, not per model)."""
    live = jobs.workers.live()
    seen = None if serving(live, queue) else jobs.workers.seen()  # needed only when no live worker serves it
    for model in sorted(models) or [None]:  # None: a worker at all
        unavailable = jobs.unavailable(model, queue=queue, live=live, seen=seen)
        if unavailable is not None:
            return unavailable
    return None
