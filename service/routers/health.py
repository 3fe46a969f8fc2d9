"""Liveness and readiness: what a load balancer or an orchestrator asks before sending work."""

from __future__ import annotations

import redis
from fastapi import APIRouter, Request

from service.errors import documented, error_response
from service.jobs import JobError
from service.schemas import Health, Ready

router = APIRouter()


@router.get("/healthz", response_model=Health, summary="The API process is up")
def healthz() -> Health:
    return Health(status="ok")


@router.get("/readyz", response_model=Ready, responses=documented(503),
            summary="A job submitted now can succeed: Redis answers and a live worker can run the default model",
            description="503 with `redis_unavailable`, `no_worker` (no worker is alive) or `model_unavailable` "
            "(no live worker can run the default model, e.g. its weights are not on the workers; the message "
            "says why). Jobs that need no model (`lambda_clip` 0) may still be accepted then.")
def readyz(request: Request):
    jobs, settings = request.app.state.jobs, request.app.state.settings
    try:
        live = jobs.live_workers()  # a Redis round trip: it raises when Redis does not answer
        problem = jobs.unavailable(settings.model, what="the default model (CTP_MODEL)", field=None, live=live)
    except redis.exceptions.RedisError:
        return error_response(503, JobError(code="redis_unavailable", message="Redis does not answer"))
    if problem is not None:
        return error_response(503, problem)
    models = sorted({spec for served in live.values() for spec, why in served.items() if why is None})
    return Ready(status="ready", redis=True, workers=len(live), models=models)
