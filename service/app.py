"""The HTTP API: a thin adapter that validates uploads, queues jobs and serves their state and results.

``create_app`` is the factory (``uvicorn --factory service.app:create_app``): it builds the job store from
the settings, puts what the routes share on ``app.state`` (the bounded mesh loader among them) and includes
the routers (``service.routers``: health, jobs, assemble, page), the error handlers (``service.errors``) and
the body limit. State lives in Redis (``service.jobs``), so any number of API processes can serve the same
jobs. ``openapi.yaml`` at the repository root is this app's schema, checked by the tests.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from typing import Any

import redis
import redis.asyncio as aioredis
from fastapi import FastAPI
from fastapi.concurrency import run_in_threadpool
from fastapi.middleware.cors import CORSMiddleware

from ctp_core.config.options import AlignOptions
from ctp_core.errors import ConfigError
from ctp_core.io import MeshLimits
from ctp_core.reading.names import NAME_MAX
from service import logs
from service.delivery import Deliverer
from service.deps import digest
from service.errors import BodyLimit, install_handlers
from service.forms import OPTIONS_DEPTH, OPTIONS_MAX, PROMPT_MAX
from service.jobs import Jobs
from service.reconcile import EVERY_S as RECONCILE_EVERY_S
from service.reconcile import reconcile
from service.routers import adjust, assemble, health, inspect, page, scenes, webhooks
from service.routers import jobs as jobs_router
from service.schemas import JobOptions
from service.settings import Settings
from service.storage import StorageUnavailable

log = logging.getLogger("ctp.service")

SWEEP_EVERY_S = 60.0

DESCRIPTION = f"""
Place one 3D object relative to another from a text prompt (Copy-Transform-Paste).

Submit two meshes and a prompt to `POST /align`, follow `GET /jobs/{{id}}` (or its server-sent
`events`), then download `result.glb`; `GET /jobs` lists the caller's jobs. `POST /assemble` builds a
scene of several objects, one stage each, as one job; `POST /scenes` builds one from a sentence ("a piano
with its stool in front of it and a metronome on top"), whose plan `POST /plans/read` shows first; `POST /align`
with `target_job` adds one object to an earlier job's scene. `POST /jobs/{{id}}/adjust` measures a placement of the
source made by hand, settles it into contact ("drop", "push") and with `save` stores it as the job's result (the
run's own at `original.glb`). Jobs run on queue workers; records and results expire after the configured TTL
(`CTP_JOB_TTL_S`). A web page for all of this is at `/`; these docs work offline (`/docs`, `/redoc`).

**Authentication.** When the service has API keys (`CTP_API_KEYS`), every call except `/healthz` and
`/readyz` needs `Authorization: Bearer <key>`, and a key sees only its own jobs (others' are 404).

**Errors.** Every error answer is `{{"error": {{"code", "message", "field"}}}}`; `code` is stable:

- 400: `invalid_request` (not multipart, malformed form), `missing_field`, `invalid_field` (a file where
  text belongs or the reverse, text that is not UTF-8), `unknown_field`, `invalid_options` (options is
  not a JSON object, is over {OPTIONS_MAX} characters or {OPTIONS_DEPTH} levels deep, or holds an integer
  beyond 64 bits, NaN or infinity), `invalid_plan` (an assembly plan that is not a JSON list of steps, or
  names a file part not sent), `invalid_field` also for `webhook_events` without `webhook`,
  `invalid_idempotency_key` (not 1 to 255 visible ASCII characters); a list field (`on`, `names`) is one part
  per item or one part holding a JSON list, and its malformed list or wrong count is `invalid_field`
- 401: `unauthorized`
- 404: `job_not_found` (also a `target_job` that is unknown or another key's), `not_found`,
  `adjustment_not_found`, `not_adjusted` (`original.glb` of a job with no saved adjustment)
- 409: `job_not_ready` (result of a job that has not succeeded, or such a `target_job`, or an adjustment of one),
  `job_finished` (cancel of an ended job), `idempotency_conflict`
  (an `Idempotency-Key` already used for a different request), `idempotency_in_progress` (the first request with
  that key is still being checked after a minute)
- 413: `request_too_large`, `mesh_file_too_large`, `mesh_too_large` (faces, glTF instances counted),
  `mesh_too_complex` (a glTF scene graph over {MeshLimits.max_nodes:,} nodes or {MeshLimits.max_depth}
  deep by default, or a mesh whose loading ran past its wall time (`CTP_LOAD_TIMEOUT_S`) or memory
  (`CTP_LOAD_MEMORY_MB`)), `image_too_large`, `too_many_stages` (`CTP_MAX_STAGES`), `scene_too_large`
  (all meshes of a job, `CTP_MAX_SCENE_FACES`)
- 415: `mesh_unknown_format` (extension not .glb, .gltf, .obj, .zip (OBJ+MTL), .ply or .stl)
- 422: `invalid_prompt` (1 to {PROMPT_MAX} characters, no control characters but tab, newline and carriage
  return), `invalid_option` (includes an integer option out of its range, and `POST /inspect`'s `up` and
  `front`), `unknown_option`,
  `invalid_name` (1 to {NAME_MAX} characters, no control characters; also a file name with control
  characters), `invalid_step` (a plan's step with a repeated name, an `on` that is not placed before it, or
  neither prompt nor image while guided),
  a description `POST /plans/read` and `POST /scenes` cannot read: `unknown_object`, `placement_cycle`,
  `placed_twice`, `nothing_placed`, `unclear_clause`, `too_few_objects`, `empty_description`,
  `invalid_description`,
  `mesh_empty`, `mesh_unreadable` (corrupt, or a glTF whose accessors, buffer views or
  buffers disagree, including a `data:` buffer whose `byteLength` is not its decoded size),
  `mesh_invalid_values` (NaN/inf), `mesh_external_reference` (glTF URIs), `mesh_zip_invalid` (bombs,
  paths out of the archive, encrypted or symbolic-link members, not exactly one mesh), `invalid_image`,
  `invalid_webhook` (not an http(s) URL with a host that resolves, or unknown `webhook_events`),
  `webhook_url_refused` (the webhook's host resolves to a loopback, private, link-local, multicast or other
  non-public address; `CTP_WEBHOOK_ALLOW_PRIVATE` allows them), `webhooks_disabled` (no `CTP_WEBHOOK_SECRET`),
  `queue_not_served` (the job's `queue` option names a queue no worker serves, live or seen within the grace;
  the message lists those served), `invalid_transform` (an adjustment's transform that is not a rotation, one
  scale and a translation), `invalid_direction` (a push without a direction)
- 429: `too_many_jobs` (queued plus running jobs per key, `CTP_MAX_ACTIVE_JOBS`; admitted atomically, so never over
  the limit however many submits race)
- 503: `redis_unavailable`; `storage_unavailable` (the object store, `CTP_STORAGE=s3`, did not answer or
  refused); `no_worker` (no worker is alive, and none was seen within the grace,
  `CTP_WORKER_GRACE_S`); `model_unavailable` (no live worker can run
  the job's model, e.g. its weights are not on the workers and downloads are off; the message says why);
  `loader_unavailable` (shutting down, or every loading process busy).
  `POST /align` and `POST /assemble` answer these up front instead of accepting a job that would fail; a job with
  `lambda_clip` 0 (geometry only) needs no model. `GET /readyz` gives the same codes for the default model.
  While a worker is being restarted (none of its queue live, one seen within the grace) jobs are judged by what it
  could run, accepted and queued, and `GET /readyz` answers 200 `restarting`.

Every 429 and 503 carries `Retry-After` (seconds): for 429 the soonest estimate of the key's running jobs (1 to
60), for 503 by code: `redis_unavailable` 2, `storage_unavailable` 5, `loader_unavailable` 10, `no_worker` 30,
`model_unavailable` 60. A query value out of its bounds is 400 `invalid_request`; a method the path does not have
is 405 `method_not_allowed`, its `Allow` listing every method of the path. Each code has one status.

**Queues.** Workers serve named queues (`CTP_QUEUES`, e.g. GPU and CPU workers); a job goes to the one its
`queue` option names, default the deployment's (`CTP_DEFAULT_QUEUE`), and is judged by that queue's workers.

**Downloads.** A job's `links.downloads` says how its result and preview answer: `stream` (200 with the
file) or `redirect` (307 to a short-lived presigned URL of the object store; follow it without the
Authorization header). `report.json` is always streamed.

**Nothing of the machine.** No answer names the server's paths or cache folders: every job answer (`GET
/jobs/{{id}}`, the list, the events, webhooks), `report.json` and every error say `<path>` where a worker wrote one
(e.g. in `guide_why`, where it looked for a model's weights).

**Webhooks, retries and waiting.** `webhook` (and `webhook_events`: `start`, `progress`, `completed`;
default `completed`) on a submit POSTs the job's events there, signed as Standard Webhooks does (headers
`webhook-id`, `webhook-timestamp`, `webhook-signature: v1,<base64 HMAC-SHA256 of "{{id}}.{{timestamp}}.{{body}}">`
with the deployment's secret), retried with back-off; the job's `webhook` says how delivery went. An
`Idempotency-Key` header makes a retried submit answer the job of the first one instead of starting another.
`Prefer: wait=N` (at most 60) answers 200 with the finished job when it ends within N seconds.

Uploads are loaded, before anything is queued, in separate loading processes with a wall-time and a
memory limit, so no upload can stall or exhaust the API.

Failed jobs carry an error too: an engine code (`canceled`, `model_unavailable` (the model failed to load
after the job was accepted), `invalid_option`, a mesh code, ...), `inputs_expired` (its uploads expired,
`CTP_JOB_TTL_S`, before a worker picked it up), `job_timeout` (`CTP_JOB_TIMEOUT_S`), `job_too_large` (the
job needed more memory than `CTP_JOB_MEMORY_MB`; the message names the stage, the worker goes on to the next job),
`worker_lost` (the worker running it missed its lease, on its second attempt: a job whose worker is lost is queued
again once; `attempts` counts them), `worker_cannot_serve` (the worker's own
`CTP_DEVICE` / `CTP_RUNTIME` / `CTP_THREADS` cannot run this job, checked when it takes the job, before anything
loads), `storage_unavailable` (the worker could not read its uploads or store its results) or `internal_error`.
An assembly's failure names its stage in the message (`stage 2/3 (plate): ...`) and in `field` (`steps.1`).
"""


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API over the Redis at ``settings.redis_url`` (required; ``ctp serve`` provides one)."""
    settings = settings or Settings()
    logs.configure(settings.log_level)
    if not settings.redis_url:
        raise ConfigError("REDIS_URL is not set; `ctp serve` starts an embedded Redis", field="REDIS_URL")
    jobs = Jobs.from_settings(settings)
    loader = settings.mesh_loader()

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        app.state.aredis = aioredis.Redis.from_url(settings.redis_url)
        reaper = asyncio.create_task(_reap_forever(jobs, settings.heartbeat_s))
        deliverer = None
        if settings.webhook_key is not None:
            deliverer = Deliverer(jobs, settings.webhook_key, allow_private=settings.webhook_allow_private,
                                  retry_s=settings.webhook_retry_s, timeout_s=settings.webhook_timeout_s)
            deliverer.start()
        try:
            yield
        finally:
            reaper.cancel()
            if deliverer is not None:
                await run_in_threadpool(deliverer.stop)
            loader.close()
            await app.state.aredis.aclose()
            jobs.redis.close()

    # The docs pages are the page router's, on vendored assets (FastAPI's default loads them from a CDN).
    app = FastAPI(title="ctp", version="0.1.0", description=DESCRIPTION, lifespan=lifespan,
                  docs_url=None, redoc_url=None)
    app.state.settings, app.state.jobs, app.state.loader = settings, jobs, loader
    app.state.key_digests = [digest(k) for k in settings.api_keys]
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["GET", "POST",
                           "DELETE"], allow_headers=["Authorization", "Content-Type"])
    app.add_middleware(BodyLimit, max_bytes=settings.max_request_bytes)
    install_handlers(app)
    app.include_router(health.router)
    app.include_router(jobs_router.router)
    app.include_router(page.router)
    app.include_router(inspect.router)
    app.mount("/static", page.static_files(), name="static")
    app.include_router(assemble.router)
    app.include_router(adjust.router)
    app.include_router(scenes.router)
    app.webhooks.include_router(webhooks.router)

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = FastAPI.openapi(app)
            for model in (AlignOptions, JobOptions):
                schema["components"]["schemas"][model.__name__] = model.model_json_schema(
                    ref_template="#/components/schemas/{model}")
            # FastAPI documents a 422 of its own on every operation with parameters; this API answers a malformed
            # request 400 invalid_request (service.errors), documented where it can happen (and a webhook receiver
            # answers what it likes: any 2xx delivers).
            for operation in (op for part in ("paths", "webhooks") for path in schema.get(part, {}).values()
                              for op in path.values()):
                if operation["responses"].get("422", {}).get("description") == "Validation Error":
                    del operation["responses"]["422"]
            for unused in ("HTTPValidationError", "ValidationError"):
                schema["components"]["schemas"].pop(unused, None)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi
    return app


async def _reap_forever(jobs: Jobs, period_s: float) -> None:
    """Reap jobs of dead workers every heartbeat period (``Jobs.reap``); from start-up on, about once a minute, put
    back queued jobs that lost their place in the queue (``service.reconcile``) and expire stored files.

    After a Redis outage, reaping waits one lease: a lease that lapsed while Redis was away is the outage's doing,
    not the worker's, and the workers, which wait outages out (``worker.outage``), renew it within a heartbeat.
    One log line per outage."""
    last_sweep = last_pass = -math.inf
    resume_at = 0.0
    down = False
    while True:
        try:
            if time.monotonic() >= resume_at:
                await run_in_threadpool(jobs.reap)
                if time.monotonic() - last_pass > RECONCILE_EVERY_S:
                    await run_in_threadpool(reconcile, jobs)
                    last_pass = time.monotonic()
            if time.monotonic() - last_sweep > SWEEP_EVERY_S:
                await run_in_threadpool(jobs.storage.sweep)
                last_sweep = time.monotonic()
            down = False
        except redis.exceptions.RedisError as exc:
            if not down:
                log.warning("reaper: %s; reaping resumes one lease after Redis answers again", exc)
            down, resume_at = True, time.monotonic() + jobs.lease_s
        except StorageUnavailable as exc:
            log.warning("reaper: %s", exc)
        await asyncio.sleep(period_s)
