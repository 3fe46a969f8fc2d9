"""The jobs API: submit an alignment, list the caller's jobs, read and cancel one, follow its events,
download its results."""

from __future__ import annotations

import json
import logging

import redis.asyncio as aioredis
from fastapi import APIRouter, Depends, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import RedirectResponse, StreamingResponse

from ctp_core.config import MAX_ALTERNATIVES
from ctp_core.errors import ConfigError
from ctp_core.reading.counts import choose
from service import forms
from service import submit as submit_
from service.chained import chained_target
from service.deps import own_job, owner
from service.errors import ApiError, documented, download_response
from service.jobs import ORIGINAL, OUTPUTS, TERMINAL, JobRecord, Jobs, alternative_blob, now, parse_record
from service.redact import report_json
from service.schemas import Accepted, JobList, JobOut, build_config

log = logging.getLogger("ctp.service")

REPORT = "report.json"  # small: always streamed, so that it can be redacted
SSE_KEEPALIVE_S = 10.0
JOBS_PAGE_MAX = 100
OFFSET_MAX = 2**53 - 1  # what every JSON client holds exactly; Redis ranges take 64-bit integers
REDIRECT = {307: {"description": "the job's `links.downloads` is `redirect`: the file is at the `Location`, a "
                  "presigned URL of the object store valid `CTP_S3_PRESIGN_S` seconds (it needs no "
                  "Authorization header)"}}
# One event of GET /jobs/{id}/events (``_sse``): its name, and the job as JSON.
SSE_EVENT = {"type": "object", "required": ["event", "data"], "properties": {
    "event": {"type": "string", "enum": ["progress", "end"]},
    "data": {"type": "string", "contentMediaType": "application/json",
             "contentSchema": {"$ref": "#/components/schemas/JobOut"}}}}

router = APIRouter()


@router.post("/align", status_code=202, response_model=Accepted, openapi_extra={"requestBody": forms.ALIGN_BODY},
             responses=submit_.RESPONSES, summary="Submit an alignment job",
             description="Two meshes and a prompt; or, with `target_job` instead of `target`, one of your succeeded "
             "jobs' result scene as the target (its objects stay separate and never move), to add one object at "
             "a time. 404 `job_not_found` for an unknown target job or another key's, 409 `job_not_ready` when "
             "it has not succeeded, 413 `scene_too_large` when the meshes together (target and source, or the target "
             "job's scene and the source) are over `CTP_MAX_SCENE_FACES`. With `webhook` the job's events are "
             "POSTed there; with `Idempotency-Key` a retried submit answers the first one's job (409 "
             "`idempotency_conflict` for the same key on a different request); with `Prefer: wait=N` a job that "
             "ends within N seconds is answered 200 with the finished job.")
async def submit(request: Request, who: str = Depends(owner), idempotency_key: str | None = submit_.IDEMPOTENCY_KEY,
                 prefer: str | None = submit_.PREFER) -> Response:
    form = await forms.read_form(request)
    return await submit_.accept(request, who, form, lambda job_id: _align_job(request, form, who, job_id),
                                idempotency_key=idempotency_key, prefer=prefer)


async def _align_job(request: Request, form, who: str, job_id: str) -> submit_.Built:
    """The alignment a ``POST /align`` form asks for, checked: its record, uploads and config."""
    settings = request.app.state.settings
    prompt, image = forms.prompt_and_image(form)
    options, queue = forms.job_options(form, settings.default_queue)
    count, arrangement = forms.copies_options(options)
    config = build_config(options, default_model=settings.model, allowed_models=settings.allowed_models,
                          image=image is not None)
    blobs: dict[str, bytes] = {}
    files: dict[str, str] = {}
    target_job, on = forms.text(form, "target_job"), forms.grounds(form)
    if on and target_job is None:
        raise ApiError(400, "invalid_field", "on names an object of a target_job's scene; give target_job", field="on")
    if target_job is not None and "target" in form:
        raise ApiError(400, "invalid_field", "give a target file or a target_job, not both", field="target")
    chained = await chained_target(request, form, who, target_job, on, prompt) if target_job is not None else None
    faces = chained.faces if chained else 0
    for role in ("source",) if chained else ("target", "source"):
        upload = forms.file(form, role)
        files[role] = forms.file_name(upload, role)
        blobs[role] = await forms.read_limited(upload, settings.max_upload_bytes, role, "mesh_file_too_large")
        faces += await run_in_threadpool(forms.check_mesh, request.app.state.loader, blobs[role], files[role],
                                         settings.mesh_limits, role)
    forms.check_scene_faces(faces, settings.max_scene_faces)  # all meshes of the job together
    if chained:
        files["target"], blobs["target"], on = chained.file, chained.data, chained.on
    if image is not None:
        blobs["image"] = await forms.read_limited(image, settings.max_image_bytes, "image", "image_too_large")
        await run_in_threadpool(forms.check_image, blobs["image"], settings.max_image_pixels)
    source_name = forms.object_name(form, "source", files["source"])
    copies, arrangement = _copies(prompt, count, arrangement, source_name, image is not None, chained is not None)
    record = JobRecord(
        id=job_id, owner=who, created_at=now(), prompt=prompt, has_image=image is not None,
        target_name=forms.object_name(form, "target", on[0] if on else files["target"]), source_name=source_name,
        target_file=files["target"], source_file=files["source"], config=config,
        target_job=target_job, on=on or None, queue=queue, downloads=settings.downloads, count=copies,
        arrangement=arrangement,
    )
    return record, blobs, [config]


def _copies(prompt: str | None, count: int | None, arrangement: str, source_name: str, image: bool,
            chained: bool) -> tuple[int, str | None]:
    """The job's copies and their arrangement (``priors.counts.choose``: 422 ``count_out_of_range``,
    ``invalid_arrangement``); several copies are prompt-guided onto an uploaded target (422 ``invalid_option``)."""
    try:
        n, kind, _ = choose(prompt, count, arrangement, source_name)
    except ConfigError as exc:
        raise ApiError(422, exc.code, exc.message, field=f"options.{exc.field}") from None
    if n > 1 and (image or chained):
        raise ApiError(422, "invalid_option", "several copies are placed by a prompt on an uploaded target: not with "
                       "an image or a target_job", field="options.count")
    return n, kind if n > 1 else None


@router.get("/jobs", response_model=JobList, responses=documented(400, 401, 503),
            summary="The caller's jobs, newest first",
            description="Jobs submitted with the caller's key (all jobs when the service has no keys) that have "
            "not expired (`CTP_JOB_TTL_S`), a page at a time.")
async def list_jobs(request: Request, who: str = Depends(owner),
                    offset: int = Query(0, ge=0, le=OFFSET_MAX, description="jobs to skip"),
                    limit: int = Query(20, ge=1, le=JOBS_PAGE_MAX, description="page size")) -> JobList:
    records, total = await run_in_threadpool(request.app.state.jobs.owned, who, offset, limit)
    after = offset + limit
    return JobList(jobs=[JobOut.of(r) for r in records], total=total, offset=offset, limit=limit,
                   next=f"/jobs?offset={after}&limit={limit}" if after < total else None)


@router.get("/jobs/{job_id}", response_model=JobOut, responses=documented(401, 404, 503), summary="A job's state")
async def get_job(job_id: str, request: Request, who: str = Depends(owner)) -> JobOut:
    return JobOut.of(await own_job(request, job_id, who))


@router.delete("/jobs/{job_id}", response_model=JobOut, summary="Cancel a job",
               description="A queued job is canceled at once (200, status canceled); a running one is "
               "flagged and stops at its next optimisation step (202, cancel_requested true).",
               responses={202: {"model": JobOut, "description": "cancel requested; the job is still running"},
                          **documented(401, 404, 409, 503)})
async def cancel_job(job_id: str, request: Request, response: Response, who: str = Depends(owner)) -> JobOut:
    record = await own_job(request, job_id, who)
    if record.status in TERMINAL:
        raise ApiError(409, "job_finished", f"job {job_id} already ended ({record.status})")
    record = await run_in_threadpool(request.app.state.jobs.cancel, job_id) or record
    response.status_code = 202 if record.status == "running" else 200
    log.info("cancel requested", extra={"job_id": job_id, "status": record.status})
    return JobOut.of(record)


@router.get("/jobs/{job_id}/events", responses={
    **documented(401, 404, 503),
    200: {"description": "`text/event-stream`: an `event: progress` whose data is the job (as GET "
                         "/jobs/{id}) whenever it changes, comment lines as keep-alives, and a last "
                         "`event: end` with the final job, after which the stream closes. The schema is one "
                         "event's (its `event` and `data` fields, as OpenAPI 3.2's `itemSchema` has it).",
          "content": {"text/event-stream": {"schema": SSE_EVENT}}}},
    response_class=StreamingResponse, summary="Server-sent progress events until the job ends")
async def job_events(job_id: str, request: Request, who: str = Depends(owner)):
    await own_job(request, job_id, who)
    state = request.app.state
    return StreamingResponse(_sse(state.aredis, state.jobs, job_id), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


ALTERNATIVE = Query(None, ge=0, lt=MAX_ALTERNATIVES, description="result.glb only: 0 for the answer (the "
                    "default), 1 to 3 for the next best distinct placements the job refined (`alternatives` in GET "
                    "/jobs/{id}); 404 `alternative_not_found` past the job's own")


def _add_output_route(name: str, media_type: str) -> None:
    """``GET /jobs/{id}/<name>``: only result.glb takes ``?alternative`` (in its schema; 400 on the others)."""

    async def download(job_id: str, request: Request, who: str = Depends(owner),
                       alternative: int | None = ALTERNATIVE) -> Response:
        return await _download(request, job_id, who, name, media_type, alternative)

    async def download_file(job_id: str, request: Request, who: str = Depends(owner)) -> Response:
        if "alternative" in request.query_params:
            raise ApiError(400, "invalid_request", f"only result.glb takes ?alternative, not {name}",
                           field="alternative")
        return await _download(request, job_id, who, name, media_type, None)

    router.add_api_route(f"/jobs/{{job_id}}/{name}", download if name == "result.glb" else download_file,
                         methods=["GET"], response_class=Response,
                         responses={**download_response(media_type, name),
                                    **({} if name == REPORT else REDIRECT), **documented(400, 401, 404, 409, 503)},
                         operation_id=f"download_{name.replace('.', '_')}", summary=f"Download {name}")


async def _download(request: Request, job_id: str, who: str, name: str, media_type: str,
                    alternative: int | None) -> Response:
    """A succeeded job's file ``name`` (``alternative``: result.glb's k-th placement), streamed or redirected;
    report.json always streamed, without the machine's paths (``service.redact``)."""
    record = await own_job(request, job_id, who)
    if record.status != "succeeded":
        raise ApiError(409, "job_not_ready", f"job {job_id} is {record.status}; results exist once it succeeded")
    if name == ORIGINAL and record.adjusted is None:
        raise ApiError(404, "not_adjusted", f"job {job_id} has no saved adjustment: its result.glb is the original")
    stored = name
    if alternative is not None:
        if alternative >= max(1, len(record.alternatives)):
            raise ApiError(404, "alternative_not_found", f"job {job_id} has {len(record.alternatives)} "
                           f"alternatives; asked for {alternative}", field="alternative")
        stored = alternative_blob(alternative)
    storage, presign_s = request.app.state.jobs.storage, request.app.state.settings.s3_presign_s
    filename = f"{job_id}-{stored}"
    # what the job's links promised, while still configured
    if record.downloads == "redirect" and presign_s and name != REPORT:
        url = await run_in_threadpool(storage.url, job_id, stored, presign_s, media_type=media_type,
                                      filename=filename)
        if url is not None:
            return RedirectResponse(url, status_code=307)
    data = await run_in_threadpool(storage.get, job_id, stored)
    if data is None:
        raise ApiError(404, "job_not_found", f"the results of job {job_id} have expired")
    if name == REPORT:
        data = report_json(json.loads(data))  # one an older worker stored unredacted is redacted here
    return Response(data, media_type=media_type, headers={"Content-Disposition": f'attachment; filename="{filename}"'})


# original.glb: the run's own scene, once an adjustment replaced result.glb (POST /jobs/{id}/adjust with save)
for _name, _media_type in {**OUTPUTS, ORIGINAL: OUTPUTS["result.glb"]}.items():
    _add_output_route(_name, _media_type)


async def _sse(aredis: aioredis.Redis, jobs: Jobs, job_id: str):
    """Subscribe first, then read the record, so no change between the two is missed."""
    pubsub = aredis.pubsub()
    await pubsub.subscribe(jobs.channel(job_id))
    try:
        record = await jobs.get_async(aredis, job_id)
        last = None
        while record is not None:
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
                record = await jobs.get_async(aredis, job_id)
            else:
                record = parse_record(message["data"])
    finally:
        await pubsub.unsubscribe()
        await pubsub.aclose()
