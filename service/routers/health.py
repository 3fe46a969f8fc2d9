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
            summary="Redis answers and at least one worker is alive")
def readyz(request: Request):
    jobs = request.app.state.jobs
    try:
        jobs.redis.ping()
        workers = jobs.workers_alive()
    except redis.exceptions.RedisError:
        return error_response(503, JobError(code="redis_unavailable", message="Redis does not answer"))
    if workers < 1:
        return error_response(503, JobError(code="not_ready", message="no worker is alive"))
    return Ready(status="ready", redis=True, workers=workers)
