"""What ``POST /align`` and ``POST /assemble`` share once their form is read: the webhook fields, the
``Idempotency-Key`` header and ``Prefer: wait``, around building and queueing the job.

Idempotency: the first request with a key claims it in Redis (``SET NX``, per owner) with its fingerprint
(a hash of the route, every field and every upload's bytes) and the id its job will have, so of two
concurrent submits with one key exactly one builds a job; the other waits for that job and answers it. While
the job is being checked the claim lives ``CLAIM_HOLD_S`` at a time, renewed by its request, so that a request
that dies there (its API process killed) frees the key within that; it is dropped when the submit is refused
(the client may fix it and retry with the key), and the transaction that queues the job keeps it as long as the
job (``Jobs.submit``), so that no crash between the two leaves a job whose key is free for a second one.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import re
from collections.abc import Awaitable, Callable

from fastapi import Header, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from redis.exceptions import RedisError
from starlette.datastructures import UploadFile

from ctp_core.config import AlignConfig
from service import forms
from service.deps import enqueue
from service.errors import ApiError, documented
from service.jobs import TERMINAL, ClaimLost, JobRecord, new_id
from service.schemas import Accepted, JobOut, links
from service.webhooks import DEFAULT_EVENTS, EVENTS, Webhook, WebhookInvalid, check_url, resolve

WAIT_MAX_S = 60  # Prefer: wait=N above this waits this long
KEY_MAX = 255
CLAIM_HOLD_S = 6  # a claim whose request stops renewing it (every third of this) is free again after this
REPLAY_WAIT_S = 60.0  # a second request with a key waits this long for the first one's job
_KEY = re.compile(rf"[\x21-\x7e]{{1,{KEY_MAX}}}")  # visible ASCII
_WAIT = re.compile(r"[0-9]{1,9}")
# Compare and delete, compare and renew: a claim is dropped or renewed only by the request that holds it.
_RELEASE = "if redis.call('GET', KEYS[1]) == ARGV[1] then return redis.call('DEL', KEYS[1]) end return 0"
_RENEW = "if redis.call('GET', KEYS[1]) == ARGV[1] then return redis.call('EXPIRE', KEYS[1], ARGV[2]) end return 0"

Built = tuple[JobRecord, dict[str, bytes], list[AlignConfig]]

IDEMPOTENCY_KEY = Header(None, alias="Idempotency-Key", description=(
    f"1 to {KEY_MAX} visible ASCII characters (a UUID, say). The same key and the same request (every field and "
    "upload byte for byte) answer the job the first one created, 200 with the job, instead of starting another; "
    "the same key with a different request is 409 `idempotency_conflict`. Keys are per API key and kept as "
    "long as the job (`CTP_JOB_TTL_S`); a refused submit does not keep its key."))
PREFER = Header(None, alias="Prefer", description=(
    f"`wait=N` (RFC 7240; N seconds, at most {WAIT_MAX_S}, larger is taken as {WAIT_MAX_S}): answer 200 with "
    "the finished job if it ends within N seconds, else the usual 202; `Preference-Applied: wait=N` says it "
    "was honoured. Other or malformed preferences are ignored."))

_APPLIED = {"Preference-Applied": {"description": "`wait=N` when the request's `Prefer: wait` was honoured",
                                   "schema": {"type": "string"}}}
RESPONSES = {
    200: {"model": JobOut, "headers": _APPLIED, "description": "the job, ended within `Prefer: wait`, or the one "
          "an earlier request with the same `Idempotency-Key` created (as it is now)"},
    202: {"headers": _APPLIED, "description": "queued (or running, after a `Prefer: wait` that ran out)"},
    **documented(400, 401, 404, 409, 413, 415, 422, 429, 503),
}


async def accept(request: Request, who: str, form, build: Callable[[str], Awaitable[Built]], *,
                 idempotency_key: str | None, prefer: str | None) -> JSONResponse:
    """Check the webhook, honour the idempotency key, build the job with ``build(job_id)`` and queue it, then
    answer: 202 (queued), or 200 with the job when it ended within the wait or the key was seen before."""
    wait_s = wait_preference(prefer)
    webhook = await read_webhook(request, form)
    claim = None
    if idempotency_key is not None:
        claim = await _Claim.take(request, who, idempotency_key, await run_in_threadpool(
            fingerprint, request.url.path, form))
        if claim.existing is not None:
            return await _answer(request, claim.existing, wait_s, replay=True)
    renewing = asyncio.create_task(claim.renew()) if claim is not None else None
    try:
        record, blobs, configs = await build(claim.job_id if claim else new_id())
        if webhook is not None:
            record = record.model_copy(update={"webhook": webhook})
        await enqueue(request, record, blobs, configs, claim=(claim.key, claim.value) if claim else None)
    except ClaimLost:
        raise ApiError(409, "idempotency_in_progress", "this request was stalled and another request with the same "
                       "Idempotency-Key took it over; retry it later", field="Idempotency-Key") from None
    except Exception:
        if claim is not None:
            await claim.release()
        raise
    finally:
        if renewing is not None:
            renewing.cancel()
    return await _answer(request, record, wait_s)


async def _answer(request: Request, record: JobRecord, wait_s: int | None, replay: bool = False) -> JSONResponse:
    state = request.app.state
    headers = {}
    if wait_s is not None:
        headers["Preference-Applied"] = f"wait={wait_s}"
        if record.status not in TERMINAL:
            record = await state.jobs.wait_async(state.aredis, record.id, wait_s) or record
    if replay or record.status in TERMINAL:
        return JSONResponse(JobOut.of(record).model_dump(mode="json"), status_code=200, headers=headers)
    accepted = Accepted(id=record.id, status=record.status, links=links(record.id, record.downloads))
    return JSONResponse(accepted.model_dump(mode="json"), status_code=202, headers=headers)


def wait_preference(prefer: str | None) -> int | None:
    """The seconds of ``Prefer: wait=N`` (RFC 7240: comma-separated ``token[=value]``, ``;`` parameters),
    at most ``WAIT_MAX_S``; None when absent or malformed (a preference a server cannot honour is ignored)."""
    for preference in (prefer or "").split(","):
        token, _, value = preference.split(";")[0].partition("=")
        if token.strip().lower() == "wait":
            value = value.strip().strip('"')
            return min(int(value), WAIT_MAX_S) if _WAIT.fullmatch(value) else None
    return None


async def read_webhook(request: Request, form) -> Webhook | None:
    """The ``webhook`` and ``webhook_events`` fields, checked: an http(s) URL whose host resolves to public
    addresses only (unless ``CTP_WEBHOOK_ALLOW_PRIVATE``), events among ``EVENTS`` (default completed)."""
    url, events = forms.text(form, "webhook"), forms.text(form, "webhook_events")
    if url is None:
        if events is not None:
            raise ApiError(400, "invalid_field", "webhook_events needs a webhook URL", field="webhook_events")
        return None
    settings = request.app.state.settings
    if settings.webhook_secret is None:
        raise ApiError(422, "webhooks_disabled", "this service has no webhook signing secret (CTP_WEBHOOK_SECRET), "
                       "so it sends no webhooks", field="webhook")
    chosen = [e.strip() for e in (events if events is not None else ",".join(DEFAULT_EVENTS)).split(",")]
    if not all(e in EVENTS for e in chosen):
        raise ApiError(422, "invalid_webhook", f"webhook_events is a comma-separated list of {', '.join(EVENTS)}; "
                       f"got {events!r}", field="webhook_events")
    try:
        host, port = check_url(url)
        await run_in_threadpool(resolve, host, port, settings.webhook_allow_private)
    except WebhookInvalid as exc:
        raise ApiError(422, exc.code, exc.message, field="webhook") from None
    return Webhook(url=url, events=list(dict.fromkeys(chosen)))


def fingerprint(path: str, form) -> str:
    """What makes two submits the same request: the route, then every field in name order (repeated ones in
    their order), a text by its value, a file by its name and bytes. Blocking: hashes the uploads."""
    digest = hashlib.sha256(path.encode())

    def part(data: bytes) -> None:
        digest.update(len(data).to_bytes(8, "big") + data)

    for name, value in sorted(form.multi_items(), key=lambda item: item[0]):
        part(name.encode("utf-8", "surrogatepass"))
        if isinstance(value, UploadFile):
            content = hashlib.sha256()
            value.file.seek(0)
            for chunk in iter(lambda f=value.file: f.read(1 << 20), b""):
                content.update(chunk)
            value.file.seek(0)
            part(b"file:" + (value.filename or "").encode("utf-8", "surrogatepass"))
            part(content.digest())
        else:
            part(b"text:" + value.encode("utf-8", "surrogatepass"))
    return digest.hexdigest()


class _Claim:
    """One request's hold on an ``Idempotency-Key`` (module docstring)."""

    def __init__(self, request: Request, key: str, value: str, job_id: str, existing: JobRecord | None):
        self.request, self.key, self.value, self.job_id, self.existing = request, key, value, job_id, existing

    @classmethod
    async def take(cls, request: Request, who: str, idempotency_key: str, print_: str) -> _Claim:
        """Claim the key, or find the job of the request that did: 409 ``idempotency_conflict`` when that
        request was a different one, ``idempotency_in_progress`` when its job is still not queued after
        ``REPLAY_WAIT_S``."""
        if not _KEY.fullmatch(idempotency_key):
            raise ApiError(400, "invalid_idempotency_key", f"Idempotency-Key must be 1 to {KEY_MAX} visible ASCII "
                           "characters", field="Idempotency-Key")
        state = request.app.state
        key = state.jobs.idempotency_key(who, idempotency_key)
        job_id = new_id()
        value = json.dumps({"fingerprint": print_, "job": job_id})
        deadline = asyncio.get_running_loop().time() + REPLAY_WAIT_S
        while True:
            if await state.aredis.set(key, value, nx=True, ex=CLAIM_HOLD_S):
                return cls(request, key, value, job_id, None)
            raw = await state.aredis.get(key)
            if raw is not None:
                held = json.loads(raw)
                if held["fingerprint"] != print_:
                    raise ApiError(409, "idempotency_conflict", "this Idempotency-Key was used for a different "
                                   "request (other fields or uploads); use a new key for a new request",
                                   field="Idempotency-Key")
                record = await state.jobs.get_async(state.aredis, held["job"])
                if record is not None:
                    return cls(request, key, value, record.id, record)
                if asyncio.get_running_loop().time() > deadline:
                    raise ApiError(409, "idempotency_in_progress", "a request with this Idempotency-Key is still "
                                   "being checked; retry it later", field="Idempotency-Key")
            await asyncio.sleep(0.1)

    async def renew(self) -> None:
        """Keep the claim while the request checks its job (until cancelled); a renewal Redis does not answer is
        tried again at the next one."""
        while True:
            await asyncio.sleep(CLAIM_HOLD_S / 3)
            with contextlib.suppress(RedisError):
                await self.request.app.state.aredis.eval(_RENEW, 1, self.key, self.value, CLAIM_HOLD_S)

    async def release(self) -> None:
        """The submit was refused: free the key (only if it is still this request's)."""
        await self.request.app.state.aredis.eval(_RELEASE, 1, self.key, self.value)
