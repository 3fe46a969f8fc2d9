"""Request dependencies shared by the routers: who is calling, and the caller's own job.

They read what ``create_app`` put on ``app.state``: ``settings``, ``jobs`` (the job store), ``aredis``
(the event loop's Redis client) and ``key_digests``.
"""

from __future__ import annotations

import hashlib
import hmac
import re

from fastapi import Request

from service.errors import ApiError
from service.jobs import JobRecord

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
    raw = await state.aredis.get(state.jobs.record_key(job_id)) if _JOB_ID.fullmatch(job_id) else None
    record = None if raw is None else JobRecord.model_validate_json(raw)
    if record is None or record.owner != who:
        raise ApiError(404, "job_not_found", f"no job {job_id!r}")
    return record
