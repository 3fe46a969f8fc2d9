"""Error answers: the ``ApiError`` routes raise, the handlers that turn every failure into the stable body,
and the documented error responses each route lists in the schema."""

from __future__ import annotations

import logging
from typing import Any

import redis
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

from ctp_core.errors import CtpError
from service.jobs import JobError
from service.redact import redact
from service.schemas import ErrorBody
from service.storage import StorageUnavailable

log = logging.getLogger("ctp.service")

HTTP_METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")  # what a 405's Allow can list

# Retry-After (s) of a 503, by code: about how long that outage lasts, so that a client neither hammers a service that
# is restarting a part nor waits much past its return (docs/service.md, "Retry-After"). redis_unavailable: the
# supervisor restarts a dead embedded Redis after 1 s and the API answers again within about 2; storage_unavailable:
# the SDK has already retried within the request, so this is more than a blip; loader_unavailable: the request has
# already waited a whole load's time limit for a loading process; no_worker: a worker is restarted within the
# supervisor's longest back-off (30 s); model_unavailable, queue_not_served (/readyz): the deployment has to change.
RETRY_AFTER_S = {"redis_unavailable": 2, "storage_unavailable": 5, "loader_unavailable": 10, "no_worker": 30,
                 "model_unavailable": 60, "queue_not_served": 60}
RETRY_AFTER_OTHER_S = 30  # a 503 of a code not listed above
RETRY_AFTER = {"Retry-After": {"required": True, "description": "seconds to wait before retrying (429: when one of "
                               "the key's jobs is likely to end; 503: by code, docs/service.md)",
                               "schema": {"type": "integer", "minimum": 1}}}

_ERRORS = {status: {"model": ErrorBody, "description": text,
                     **({"headers": RETRY_AFTER} if status in (429, 503) else {})} for status, text in {
    400: "malformed request", 401: "missing or unknown API key", 404: "unknown job (or another key's)",
    409: "the job is not in a state that allows this, or an Idempotency-Key conflicts",
    413: "an upload is over a limit",
    415: "unsupported mesh format", 422: "invalid input", 429: "too many active jobs for this key",
    503: "Redis, the object store, the workers, the model or the mesh loaders are unavailable (redis_unavailable, "
         "storage_unavailable, no_worker, model_unavailable, loader_unavailable)",
}.items()}


class ApiError(Exception):
    """An error answer: HTTP status plus the stable body."""

    def __init__(self, status: int, code: str, message: str, field: str | None = None, headers=None):
        super().__init__(message)
        self.status, self.body, self.headers = status, JobError(code=code, message=message, field=field), headers


def error_response(status: int, error: JobError, headers=None) -> JSONResponse:
    """The stable error body, its message without the machine's paths (``service.redact``: any caller may read it);
    a 503 carries its ``Retry-After`` (a 429's comes with the error: ``Jobs.retry_after``)."""
    error = error.model_copy(update={"message": redact(error.message)})
    if status == 503:
        headers = {"Retry-After": str(RETRY_AFTER_S.get(error.code, RETRY_AFTER_OTHER_S)), **(headers or {})}
    return JSONResponse(ErrorBody(error=error).model_dump(mode="json"), status_code=status, headers=headers)


def documented(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """The schema's error responses for these statuses."""
    return {s: _ERRORS[s] for s in statuses}


def download_response(media_type: str, description: str) -> dict[int | str, dict[str, Any]]:
    """The schema's 200 response for a file download: bytes, or a JSON object for a JSON file."""
    schema = {"type": "object"} if media_type == "application/json" else {"type": "string", "format": "binary"}
    return {200: {"description": description, "content": {media_type: {"schema": schema}}}}


def install_handlers(app: FastAPI) -> None:
    """Every failure a route can meet answers with the stable error body, never a traceback."""

    @app.exception_handler(ApiError)
    async def _api_error(_request: Request, exc: ApiError):
        return error_response(exc.status, exc.body, exc.headers)

    @app.exception_handler(CtpError)
    async def _engine_error(_request: Request, exc: CtpError):
        return error_response(422, JobError(**exc.to_dict()))

    @app.exception_handler(redis.exceptions.ConnectionError)
    @app.exception_handler(redis.exceptions.TimeoutError)
    async def _redis_down(_request: Request, exc: Exception):
        log.error("redis unavailable: %s", exc)
        return error_response(503, JobError(code="redis_unavailable", message="the job store is unreachable"))

    @app.exception_handler(StorageUnavailable)
    async def _storage_down(_request: Request, exc: StorageUnavailable):
        log.error("storage unavailable: %s", exc)
        return error_response(503, JobError(code="storage_unavailable", message="the object store that holds "
                                            "uploads and results is unreachable or refused the request"))

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException):
        code = {404: "not_found", 405: "method_not_allowed"}.get(exc.status_code, "invalid_request")
        headers = exc.headers
        if exc.status_code == 405:  # Starlette's Allow names only the first route of the path
            headers = {**(headers or {}), "Allow": ", ".join(_allowed(request))}
        return error_response(exc.status_code, JobError(code=code, message=str(exc.detail)), headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid(_request: Request, exc: RequestValidationError):
        err = exc.errors()[0]
        return error_response(400, JobError(code="invalid_request", message=str(err.get("msg")),
                                            field=".".join(str(p) for p in err.get("loc", ())[1:]) or None))


def _allowed(request: Request) -> list[str]:
    """The methods the app routes at the request's path, asked of its router one method at a time (a path's
    methods can be spread over routes, and FastAPI nests included routers)."""
    return [method for method in HTTP_METHODS if any(
        route.matches({**request.scope, "method": method})[0] == Match.FULL for route in request.app.router.routes)]


class BodyLimit:
    """ASGI middleware: refuse request bodies over the limit while they stream in, declared length or not."""

    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            response = error_response(413, self._error())
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
