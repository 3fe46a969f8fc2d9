"""Liveness and readiness: what a load balancer or an orchestrator asks before sending work."""

from __future__ import annotations

import redis
from fastapi import APIRouter, Request

from ctp_core.config import AUTO, DEFAULT_MODEL
from ctp_core.guide.selection import GuideChoice, unguided
from service.errors import documented, error_response
from service.jobs import JobError
from service.redact import redact
from service.schemas import Health, Ready
from service.workers import served_queues, serving

router = APIRouter()


@router.get("/healthz", response_model=Health, summary="The API process is up")
def healthz() -> Health:
    return Health(status="ok")


@router.get("/readyz", response_model=Ready, responses=documented(503),
            summary="A job submitted now can succeed: Redis answers and a worker can run the default model",
            description="Every 200 says what guides jobs with default options (`guide`, `why`; with CTP_MODEL "
            "`auto` and no worker with the default model's weights, `none` and the command that gets them, "
            "`get_model`). 200 `ready` when a live worker of the default queue can run the default model; 200 "
            "`restarting` (with `since_s`) when no worker of the default queue is live but one that could was seen "
            "within the grace (`CTP_WORKER_GRACE_S`, e.g. a worker being restarted): jobs are accepted then and "
            "wait in the queue until a worker is back. 503 with `redis_unavailable`, `no_worker` (no worker has "
            "been seen for longer than the grace), `queue_not_served` (workers are live, but none serves the "
            "default queue, `CTP_DEFAULT_QUEUE`) or `model_unavailable` (no worker can run the default model, "
            "e.g. its weights are not on the workers; the message says why). Jobs that need no model "
            "(`lambda_clip` 0), or that ask for another queue, may still be accepted then.")
def readyz(request: Request):
    jobs, settings = request.app.state.jobs, request.app.state.settings
    try:
        live = jobs.workers.live()  # a Redis round trip: it raises when Redis does not answer
        seen = jobs.workers.seen()
        problem = jobs.unavailable(settings.model, what="the default model (CTP_MODEL)", field=None, live=live,
                                   seen=seen)
    except redis.exceptions.RedisError:
        return error_response(503, JobError(code="redis_unavailable", message="Redis does not answer"))
    if problem is not None:
        return error_response(503, problem)
    # Each queue as the submits judge it: by its live workers, else by those seen within the grace.
    names = served_queues(live, seen)
    queues = {name: _runnable((serving(live, name) or serving(seen, name)).values()) for name in names}
    models, live_default = queues[settings.default_queue], serving(live, settings.default_queue)
    guide = _guide(settings.model, live_default or serving(seen, settings.default_queue))
    if live_default:
        return Ready(status="ready", redis=True, workers=len(live), models=models, queues=queues, **guide)
    since_s = min(s.since_s for s in seen.values() if settings.default_queue in s.queues)
    return Ready(status="restarting", redis=True, workers=len(live), models=models, queues=queues, since_s=since_s,
                 **guide)


def _guide(model: str, offers: dict[str, dict[str, str | None]]) -> dict[str, str | None]:
    """What guides jobs with default options (``Ready.guide``): CTP_MODEL when it names a model; under auto the
    default model where a worker can run it, else none, with the workers' reason and the command that fixes it
    (without the paths the workers name: ``service.redact``)."""
    if model != AUTO:
        choice = GuideChoice(model, "named by CTP_MODEL")
    else:
        reasons = {served.get(DEFAULT_MODEL, "no worker offers it") for served in offers.values()}
        choice = (GuideChoice(DEFAULT_MODEL, "auto: a worker has the weights of the default model") if None in reasons
                  else unguided("; ".join(sorted(reasons))))
    return {key: value and redact(value) for key, value in choice.to_dict().items()}


def _runnable(offers) -> list[str]:
    """The model specs the offers can run (a spec that is a path on the workers redacted)."""
    return sorted({redact(spec) for served in offers for spec, why in served.items() if why is None})
