"""Adjust a succeeded alignment by hand (``service.adjustments``): queue an adjustment on the job's queue, read it.

The API checks what it can without the engine (the job, the transform, the direction, a worker for the queue)
and queues; a worker settles, measures and saves (``worker.tasks.run_adjustment``).
"""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse

from ctp_core.geometry import frames
from service import submit as submit_
from service.adjustments import ENDED, Adjustment, AdjustmentRecord, Adjustments, AdjustRequest
from service.deps import check_workers, own_job, owner
from service.errors import ApiError, documented
from service.jobs import JobRecord

POLL_S = 0.2  # Prefer: wait reads the adjustment this often (adjustments take a second or so)

router = APIRouter()


@router.post("/jobs/{job_id}/adjust", status_code=202, response_model=Adjustment, summary="Adjust a result by hand",
             responses={200: {"model": Adjustment, "description": "it ended within `Prefer: wait`"},
                        **documented(400, 401, 404, 409, 413, 422, 503)},
             description="Measure a placement of the source (a person moved it: the page's handles) against the "
             "target as the search measures its poses, first settling it into contact with `settle` drop (along "
             "the target's up) or push (along `direction`), and with `save` store it as the job's result "
             "(result.glb and report.json, `adjusted` true; the run's own GLB stays at original.glb; downloads and "
             "`target_job` chaining use the adjusted scene). A short job on the job's queue, at its front: 202 "
             "with the adjustment to GET until it ends, or 200 once ended within `Prefer: wait=N`. An assembly "
             "(POST /assemble, POST /scenes) adjusts one placed object at a time (`object`) against all the others, "
             "every relation of the scene judged again (`whole`). 404 "
             "`job_not_found`, 409 `job_not_ready` (the job has not succeeded), "
             "422 `invalid_object` (an assembly's object missing, unknown or the base), "
             "422 `invalid_copy` (a job of several copies adjusts one at a time: `copy_index`), "
             "422 `invalid_transform` (not a rotation, one scale and a translation) or `invalid_direction`, 503 "
             "`no_worker`.")
async def adjust(job_id: str, body: AdjustRequest, request: Request, who: str = Depends(owner),
                 prefer: str | None = submit_.PREFER) -> JSONResponse:
    record = await own_job(request, job_id, who)
    if record.status != "succeeded":
        raise ApiError(409, "job_not_ready", f"job {job_id} is {record.status}; only a succeeded job can be adjusted")
    _check_object(record, body)
    if (body.copy_index is None) != (record.count == 1) or (body.copy_index or 1) > record.count:
        wanted = f"copy_index is 1 to {record.count}" if record.count > 1 else "it places one source: no copy_index"
        raise ApiError(422, "invalid_copy", f"job {job_id}: {wanted}", field="copy_index")
    try:
        frames.checked_similarity(body.transform, frames.SOURCE_FILE, frames.TARGET_FILE)
    except ValueError as exc:
        raise ApiError(422, "invalid_transform", f"transform: {exc}", field="transform") from None
    _check_direction(body)
    await check_workers(request, set(), record.queue)  # geometry only: any worker of the job's queue
    adjustments = Adjustments(request.app.state.jobs)
    queued = await run_in_threadpool(adjustments.submit, job_id, who, record.queue, body)
    wait_s = submit_.wait_preference(prefer)
    headers = {}
    if wait_s is not None:
        headers["Preference-Applied"] = f"wait={wait_s}"
        queued = await _wait(adjustments, queued, wait_s)
    return JSONResponse(queued.out().model_dump(mode="json"), status_code=200 if queued.status in ENDED else 202,
                        headers=headers)


@router.get("/jobs/{job_id}/adjust/{adjustment_id}", response_model=Adjustment, responses=documented(401, 404, 503),
            summary="An adjustment's state and outcome")
async def get_adjustment(job_id: str, adjustment_id: str, request: Request, who: str = Depends(owner)) -> Adjustment:
    await own_job(request, job_id, who)
    found = await run_in_threadpool(Adjustments(request.app.state.jobs).get, adjustment_id)
    if found is None or found.job != job_id or found.owner != who:
        raise ApiError(404, "adjustment_not_found", f"job {job_id} has no adjustment {adjustment_id!r}")
    return found.out()


def _check_object(record: JobRecord, body: AdjustRequest) -> None:
    """An assembly adjusts one placed object, named (422 ``invalid_object``); an alignment names none."""
    placed = [step.name for step in record.steps]
    if record.kind != "assemble":
        if body.object is not None:
            raise ApiError(422, "invalid_object", f"job {record.id} places one source: no object", field="object")
    elif body.object not in placed:
        said = "the base stays put" if body.object == record.target_name else (
            "which one: object" if body.object is None else f"it has no placed object {body.object!r}")
        raise ApiError(422, "invalid_object", f"job {record.id} is a scene ({said}); its placed objects are "
                       f"{', '.join(placed)}", field="object")


def _check_direction(body: AdjustRequest) -> None:
    """A push needs a direction (422 ``invalid_direction``); one sent with another settle must be one too."""
    if body.settle != "push" and body.direction is None:
        return
    try:
        frames.checked_direction(body.direction)
    except ValueError as exc:
        raise ApiError(422, "invalid_direction", f"direction (target file frame; push moves the source along it): "
                       f"{exc}", field="direction") from None


async def _wait(adjustments: Adjustments, record: AdjustmentRecord, wait_s: float) -> AdjustmentRecord:
    """The adjustment once ended, or as it is after ``wait_s``."""
    deadline = asyncio.get_running_loop().time() + wait_s
    while record.status not in ENDED and asyncio.get_running_loop().time() < deadline:
        await asyncio.sleep(POLL_S)
        record = await run_in_threadpool(adjustments.get, record.id) or record
    return record
