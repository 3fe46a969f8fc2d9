"""The HTTP API: a thin adapter that validates uploads, queues jobs and serves their state and results.

Everything a worker would refuse is refused here first, before anything is queued: meshes are parsed
with ``ctp_core.io.load_mesh`` under the service limits, options are merged into an ``AlignConfig``.
State lives in Redis (``service.jobs``), so any number of API processes can serve the same jobs.
``create_app`` is the factory (``uvicorn --factory service.app:create_app``); ``openapi.yaml`` at the
repository root is this app's schema, checked by the tests.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import io
import json
import logging
import re
import time
from pathlib import PurePath
from typing import Any

import redis
import redis.asyncio as aioredis
from fastapi import Depends, FastAPI, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse, Response, StreamingResponse
from PIL import Image, UnidentifiedImageError
from starlette.datastructures import UploadFile
from starlette.exceptions import HTTPException as StarletteHTTPException

from ctp_core.errors import ConfigError, CtpError, MeshError
from ctp_core.io import validate_upload
from service import logs
from service.jobs import OUTPUTS, TERMINAL, JobError, JobRecord, Jobs, TooManyJobs, new_id, now
from service.schemas import Accepted, AlignOptions, ErrorBody, Health, JobOut, Ready, build_config, links
from service.settings import Settings
from service.storage import open_storage

log = logging.getLogger("ctp.service")

PROMPT_MAX = 500
NAME_MAX = 100
FORM_FIELDS = {"target", "source", "prompt", "image", "options", "target_name", "source_name"}
SSE_KEEPALIVE_S = 10.0
SWEEP_EVERY_S = 60.0
_JOB_ID = re.compile(r"[0-9a-f]{32}")

# MeshError codes that are not 422.
_MESH_STATUS = {"mesh_file_too_large": 413, "mesh_too_large": 413, "mesh_unknown_format": 415}

DESCRIPTION = f"""
Place one 3D object relative to another from a text prompt (Copy-Transform-Paste).

Submit two meshes and a prompt to `POST /align`, follow `GET /jobs/{{id}}` (or its server-sent
`events`), then download `result.glb`. Jobs run on queue workers; records and results expire after
the configured TTL (`CTP_JOB_TTL_S`).

**Authentication.** When the service has API keys (`CTP_API_KEYS`), every call except `/healthz` and
`/readyz` needs `Authorization: Bearer <key>`, and a key sees only its own jobs (others' are 404).

**Errors.** Every error answer is `{{"error": {{"code", "message", "field"}}}}`; `code` is stable:

- 400: `invalid_request` (not multipart, malformed form), `missing_field`, `invalid_field` (a file where
  text belongs or the reverse), `unknown_field`, `invalid_options` (options is not a JSON object)
- 401: `unauthorized`
- 404: `job_not_found`, `not_found`
- 409: `job_not_ready` (result of a job that has not succeeded), `job_finished` (cancel of an ended job)
- 413: `request_too_large`, `mesh_file_too_large`, `mesh_too_large` (faces), `image_too_large`
- 415: `mesh_unknown_format` (extension not .glb, .gltf, .obj, .zip (OBJ+MTL), .ply or .stl)
- 422: `invalid_prompt` (1 to {PROMPT_MAX} characters), `invalid_option`, `unknown_option`, `invalid_name`,
  `mesh_empty`, `mesh_unreadable`, `mesh_invalid_values` (NaN/inf), `mesh_external_reference` (glTF
  URIs), `mesh_zip_invalid`, `invalid_image`
- 429: `too_many_jobs` (queued plus running jobs per key, `CTP_MAX_ACTIVE_JOBS`)
- 503: `redis_unavailable`, `not_ready`

Failed jobs carry an error too: an engine code (`canceled`, `model_unavailable`, `invalid_option`, a
mesh code, ...), `job_timeout` (`CTP_JOB_TIMEOUT_S`), `worker_lost` (its worker was killed or lost
its machine; not retried) or `internal_error`.
"""

_ERRORS = {status: {"model": ErrorBody, "description": text} for status, text in {
    400: "malformed request", 401: "missing or unknown API key", 404: "unknown job (or another key's)",
    409: "the job is not in a state that allows this", 413: "an upload is over a limit",
    415: "unsupported mesh format", 422: "invalid input", 429: "too many active jobs for this key",
    503: "Redis or the workers are unavailable",
}.items()}


def _errors(*statuses: int) -> dict[int | str, dict[str, Any]]:
    return {s: _ERRORS[s] for s in statuses}


def _binary(media_type: str, description: str) -> dict[int | str, dict[str, Any]]:
    return {200: {"description": description,
                  "content": {media_type: {"schema": {"type": "string", "format": "binary"}}}}}


def _file_field(description: str) -> dict[str, Any]:
    return {"type": "string", "format": "binary", "description": description}


ALIGN_BODY = {
    "required": True,
    "content": {"multipart/form-data": {"schema": {
        "type": "object",
        "required": ["target", "source"],
        "properties": {
            "target": _file_field("the mesh that stays put (GLB, glTF with embedded buffers, OBJ, OBJ+MTL in a "
                                  ".zip, PLY, STL); the extension of the file name gives the format"),
            "source": _file_field("the mesh to place, same formats"),
            "prompt": {"type": "string", "minLength": 1, "maxLength": PROMPT_MAX,
                       "description": "what the arrangement should look like; required unless `image` is given"},
            "image": _file_field("reference picture (PNG or JPEG) for image-guided alignment instead of the text"),
            "options": {"type": "string", "contentMediaType": "application/json",
                        "contentSchema": {"$ref": "#/components/schemas/AlignOptions"},
                        "description": "JSON object of run options (AlignOptions)"},
            "target_name": {"type": "string", "maxLength": NAME_MAX,
                            "description": "what the target is (\"sundae\"), for the scene priors; "
                            "default: its file name"},
            "source_name": {"type": "string", "maxLength": NAME_MAX,
                            "description": "what the source is (\"cherry\"); default: its file name"},
        },
    }}},
}


class ApiError(Exception):
    """An error answer: HTTP status plus the stable body."""

    def __init__(self, status: int, code: str, message: str, field: str | None = None, headers=None):
        super().__init__(message)
        self.status, self.body, self.headers = status, JobError(code=code, message=message, field=field), headers


def _error_response(status: int, error: JobError, headers=None) -> JSONResponse:
    return JSONResponse(ErrorBody(error=error).model_dump(mode="json"), status_code=status, headers=headers)


class BodyLimit:
    """Refuse request bodies over the limit while they stream in, declared length or not."""

    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            response = _error_response(413, self._error())
            return await response(scope, receive, send)
        seen = 0

        async def limited():
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                raise ApiError(413, **self._error().model_dump())
            return message

        await self.app(scope, limited, send)

    def _error(self) -> JobError:
        return JobError(code="request_too_large", message=f"the request body is over {self.max_bytes} bytes")


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API over the Redis at ``settings.redis_url`` (required; ``ctp serve`` provides one)."""
    settings = settings or Settings()
    logs.configure(settings.log_level)
    if not settings.redis_url:
        raise ConfigError("REDIS_URL is not set; `ctp serve` starts an embedded Redis", field="REDIS_URL")
    client = redis.Redis.from_url(settings.redis_url, health_check_interval=30)
    jobs = Jobs(client, open_storage(client, settings.queue, settings.job_ttl_s, settings.storage_dir),
                prefix=settings.queue, ttl_s=settings.job_ttl_s, job_timeout_s=settings.job_timeout_s,
                lease_s=settings.lease_s)
    key_digests = [_digest(k) for k in settings.api_keys]
    limits = settings.mesh_limits

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        app.state.aredis = aioredis.Redis.from_url(settings.redis_url)
        reaper = asyncio.create_task(_reap_forever(jobs, settings.heartbeat_s))
        try:
            yield
        finally:
            reaper.cancel()
            await app.state.aredis.aclose()
            client.close()

    app = FastAPI(title="ctp", version="0.1.0", description=DESCRIPTION, lifespan=lifespan)
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["GET", "POST",
                           "DELETE"], allow_headers=["Authorization", "Content-Type"])
    app.add_middleware(BodyLimit, max_bytes=settings.max_request_bytes)

    @app.exception_handler(ApiError)
    async def _api_error(_request: Request, exc: ApiError):
        return _error_response(exc.status, exc.body, exc.headers)

    @app.exception_handler(CtpError)
    async def _engine_error(_request: Request, exc: CtpError):
        return _error_response(422, JobError(**exc.to_dict()))

    @app.exception_handler(redis.exceptions.ConnectionError)
    @app.exception_handler(redis.exceptions.TimeoutError)
    async def _redis_down(_request: Request, exc: Exception):
        log.error("redis unavailable: %s", exc)
        return _error_response(503, JobError(code="redis_unavailable", message="the job store is unreachable"))

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(_request: Request, exc: StarletteHTTPException):
        code = "not_found" if exc.status_code == 404 else "invalid_request"
        return _error_response(exc.status_code, JobError(code=code, message=str(exc.detail)), exc.headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid(_request: Request, exc: RequestValidationError):
        err = exc.errors()[0]
        return _error_response(400, JobError(code="invalid_request", message=str(err.get("msg")),
                                             field=".".join(str(p) for p in err.get("loc", ())[1:]) or None))

    async def owner(request: Request) -> str:
        """The caller's identity: a digest of its API key, or "public" when the service has none."""
        if not key_digests:
            return "public"
        scheme, _, token = request.headers.get("authorization", "").partition(" ")
        digest = _digest(token.strip()) if scheme.lower() == "bearer" and token.strip() else ""
        if not any(hmac.compare_digest(digest, d) for d in key_digests):
            raise ApiError(401, "unauthorized", "send Authorization: Bearer <API key>",
                           headers={"WWW-Authenticate": "Bearer"})
        return digest

    async def own_job(request: Request, job_id: str, who: str) -> JobRecord:
        """The caller's job, read on the event loop (the hot path: clients poll it)."""
        raw = await request.app.state.aredis.get(jobs.record_key(job_id)) if _JOB_ID.fullmatch(job_id) else None
        record = None if raw is None else JobRecord.model_validate_json(raw)
        if record is None or record.owner != who:
            raise ApiError(404, "job_not_found", f"no job {job_id!r}")
        return record

    @app.get("/healthz", response_model=Health, summary="The API process is up")
    def healthz() -> Health:
        return Health(status="ok")

    @app.get("/readyz", response_model=Ready, responses=_errors(503),
             summary="Redis answers and at least one worker is alive")
    def readyz():
        try:
            client.ping()
            workers = jobs.workers_alive()
        except redis.exceptions.RedisError:
            return _error_response(503, JobError(code="redis_unavailable", message="Redis does not answer"))
        if workers < 1:
            return _error_response(503, JobError(code="not_ready", message="no worker is alive"))
        return Ready(status="ready", redis=True, workers=workers)

    @app.post("/align", status_code=202, response_model=Accepted, openapi_extra={"requestBody": ALIGN_BODY},
              responses=_errors(400, 401, 413, 415, 422, 429, 503), summary="Submit an alignment job")
    async def submit(request: Request, who: str = Depends(owner)) -> Accepted:
        form = await _read_form(request)
        prompt, image = _prompt_and_image(form)
        options = _options(form)
        config = build_config(options, default_model=settings.model, allowed_models=settings.allowed_models)
        blobs: dict[str, bytes] = {}
        files: dict[str, str] = {}
        for role in ("target", "source"):
            upload = _file(form, role)
            files[role] = PurePath(upload.filename or role).name
            blobs[role] = await _read_limited(upload, settings.max_upload_bytes, role, "mesh_file_too_large")
            await run_in_threadpool(_check_mesh, blobs[role], files[role], limits, role)
        if image is not None:
            blobs["image"] = await _read_limited(image, settings.max_image_bytes, "image", "image_too_large")
            await run_in_threadpool(_check_image, blobs["image"], settings.max_image_pixels)
        record = JobRecord(
            id=new_id(), owner=who, created_at=now(), prompt=prompt, has_image=image is not None,
            target_name=_object_name(form, "target", files["target"]),
            source_name=_object_name(form, "source", files["source"]),
            target_file=files["target"], source_file=files["source"], config=config.model_dump(mode="json"),
        )
        try:
            await run_in_threadpool(jobs.submit, record, blobs, settings.max_active_jobs)
        except TooManyJobs as exc:
            raise ApiError(429, "too_many_jobs", str(exc)) from None
        return Accepted(id=record.id, status="queued", links=links(record.id))

    @app.get("/jobs/{job_id}", response_model=JobOut, responses=_errors(401, 404), summary="A job's state")
    async def get_job(job_id: str, request: Request, who: str = Depends(owner)) -> JobOut:
        return JobOut.of(await own_job(request, job_id, who))

    @app.delete("/jobs/{job_id}", response_model=JobOut, summary="Cancel a job",
                description="A queued job is canceled at once (200, status canceled); a running one is "
                "flagged and stops at its next optimisation step (202, cancel_requested true).",
                responses={202: {"model": JobOut, "description": "cancel requested; the job is still running"},
                           **_errors(401, 404, 409)})
    async def cancel_job(job_id: str, request: Request, response: Response, who: str = Depends(owner)) -> JobOut:
        record = await own_job(request, job_id, who)
        if record.status in TERMINAL:
            raise ApiError(409, "job_finished", f"job {job_id} already ended ({record.status})")
        record = await run_in_threadpool(jobs.cancel, job_id) or record
        response.status_code = 202 if record.status == "running" else 200
        log.info("cancel requested", extra={"job_id": job_id, "status": record.status})
        return JobOut.of(record)

    @app.get("/jobs/{job_id}/events", responses={
        **_errors(401, 404),
        200: {"description": "`text/event-stream`: an `event: progress` whose data is the job (as GET "
                             "/jobs/{id}) whenever it changes, comment lines as keep-alives, and a last "
                             "`event: end` with the final job, after which the stream closes.",
              "content": {"text/event-stream": {"schema": {"type": "string"}}}}},
        response_class=StreamingResponse, summary="Server-sent progress events until the job ends")
    async def job_events(job_id: str, request: Request, who: str = Depends(owner)):
        await own_job(request, job_id, who)
        return StreamingResponse(_sse(request.app.state.aredis, jobs, job_id), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})

    for name, media_type in OUTPUTS.items():
        _add_output_route(app, name, media_type, jobs, own_job, owner)

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = FastAPI.openapi(app)
            schema["components"]["schemas"]["AlignOptions"] = AlignOptions.model_json_schema(
                ref_template="#/components/schemas/{model}")
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi
    return app


def _add_output_route(app: FastAPI, name: str, media_type: str, jobs: Jobs, own_job, owner) -> None:
    async def download(job_id: str, request: Request, who: str = Depends(owner)) -> Response:
        record = await own_job(request, job_id, who)
        if record.status != "succeeded":
            raise ApiError(409, "job_not_ready", f"job {job_id} is {record.status}; results exist once it succeeded")
        data = await run_in_threadpool(jobs.storage.get, job_id, name)
        if data is None:
            raise ApiError(404, "job_not_found", f"the results of job {job_id} have expired")
        return Response(data, media_type=media_type,
                        headers={"Content-Disposition": f'attachment; filename="{job_id}-{name}"'})

    app.add_api_route(f"/jobs/{{job_id}}/{name}", download, methods=["GET"], response_class=Response,
                      responses={**_binary(media_type, name), **_errors(401, 404, 409)},
                      operation_id=f"download_{name.replace('.', '_')}", summary=f"Download {name}")


async def _reap_forever(jobs: Jobs, period_s: float) -> None:
    """Fail jobs of dead workers every heartbeat period; expire stored files about once a minute."""
    last_sweep = 0.0
    while True:
        try:
            await run_in_threadpool(jobs.reap)
            if time.monotonic() - last_sweep > SWEEP_EVERY_S:
                await run_in_threadpool(jobs.storage.sweep)
                last_sweep = time.monotonic()
        except redis.exceptions.RedisError as exc:
            log.warning("reaper: redis unavailable: %s", exc)
        await asyncio.sleep(period_s)


async def _sse(aredis: aioredis.Redis, jobs: Jobs, job_id: str):
    """Subscribe first, then read the record, so no change between the two is missed."""
    pubsub = aredis.pubsub()
    await pubsub.subscribe(jobs.channel(job_id))
    try:
        raw = await aredis.get(jobs.record_key(job_id))
        last = None
        while raw is not None:
            record = JobRecord.model_validate_json(raw)
            data = JobOut.of(record).model_dump_json()
            ended = record.status in TERMINAL
            if data != last:
                yield f"event: {'end' if ended else 'progress'}\ndata: {data}\n\n"
                last = data
            if ended:
                return
            message = await pubsub.get_message(ignore_subscribe_messages=True, timeout=SSE_KEEPALIVE_S)
            if message is None:
                yield ": keep-alive\n\n"
                raw = await aredis.get(jobs.record_key(job_id))
            else:
                raw = message["data"]
    finally:
        await pubsub.unsubscribe()
        await pubsub.aclose()


def _digest(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()[:32]


async def _read_form(request: Request):
    if not request.headers.get("content-type", "").startswith("multipart/form-data"):
        raise ApiError(400, "invalid_request", "send multipart/form-data (fields target, source, prompt, options)")
    try:
        form = await request.form(max_files=3, max_fields=8)
    except ApiError:
        raise
    except Exception as exc:  # python-multipart and Starlette raise several types for a broken body
        raise ApiError(400, "invalid_request", f"malformed multipart body: {exc}") from None
    for key in form:
        if key not in FORM_FIELDS:
            raise ApiError(400, "unknown_field", f"unknown form field {key!r}; known: {', '.join(sorted(FORM_FIELDS))}",
                           field=key)
    return form


def _text(form, name: str) -> str | None:
    value = form.get(name)
    if isinstance(value, UploadFile):
        raise ApiError(400, "invalid_field", f"{name} must be a text field, not a file", field=name)
    return value


def _file(form, name: str) -> UploadFile:
    value = form.get(name)
    if value is None:
        raise ApiError(400, "missing_field", f"{name} is required (a file)", field=name)
    if not isinstance(value, UploadFile):
        raise ApiError(400, "invalid_field", f"{name} must be a file upload, not text", field=name)
    return value


def _prompt_and_image(form) -> tuple[str | None, UploadFile | None]:
    prompt = _text(form, "prompt")
    image = _file(form, "image") if "image" in form else None
    if prompt is None and image is None:
        raise ApiError(400, "missing_field", "give a prompt (or an image for image-guided alignment)", field="prompt")
    if prompt is not None and not 1 <= len(prompt.strip()) <= PROMPT_MAX:
        raise ApiError(422, "invalid_prompt", f"the prompt must have 1 to {PROMPT_MAX} characters", field="prompt")
    return (prompt.strip() if prompt is not None else None), image


def _options(form) -> dict[str, Any]:
    raw = _text(form, "options")
    if raw is None or not raw.strip():
        return {}
    try:
        options = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise ApiError(400, "invalid_options", f"options is not JSON: {exc}", field="options") from None
    if not isinstance(options, dict):
        raise ApiError(400, "invalid_options", "options must be a JSON object", field="options")
    return options


def _object_name(form, role: str, filename: str) -> str:
    name = _text(form, f"{role}_name")
    if name is None:
        return PurePath(filename).stem.replace("_", " ").replace("-", " ").strip() or role
    if not 1 <= len(name.strip()) <= NAME_MAX:
        raise ApiError(422, "invalid_name", f"{role}_name must have 1 to {NAME_MAX} characters",
                       field=f"{role}_name")
    return name.strip()


async def _read_limited(upload: UploadFile, max_bytes: int, field: str, code: str) -> bytes:
    if upload.size is not None and upload.size > max_bytes:
        raise ApiError(413, code, f"{field} is over the {max_bytes}-byte limit", field=field)
    return await upload.read()


def _check_mesh(data: bytes, filename: str, limits, role: str) -> None:
    """Parse exactly as the worker will, so a queued job never fails on its input."""
    started = time.perf_counter()
    try:
        validate_upload(data, filename, limits)
    except MeshError as exc:
        raise ApiError(_MESH_STATUS.get(exc.code, 422), exc.code, exc.message, field=role) from None
    except CtpError as exc:
        raise ApiError(422, exc.code, exc.message, field=role) from None
    log.debug("mesh checked", extra={"duration_ms": round(1000 * (time.perf_counter() - started))})


def _check_image(data: bytes, max_pixels: int) -> None:
    try:
        with Image.open(io.BytesIO(data)) as img:
            if img.width * img.height > max_pixels:
                raise ApiError(413, "image_too_large", f"the image has over {max_pixels} pixels", field="image")
            img.convert("RGB").load()
    except (UnidentifiedImageError, OSError, Image.DecompressionBombError) as exc:
        raise ApiError(422, "invalid_image", f"the image could not be read: {exc}", field="image") from None
