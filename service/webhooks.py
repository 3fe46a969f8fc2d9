"""Webhooks: what a job's subscription is, how a delivery is signed, which URLs may be called, and the
outbox in Redis that carries events from whoever changed the job to the deliverer (``service.delivery``).

An event is written to the outbox in the same Redis transaction as the change of the job that caused it
(``Jobs._update``), wherever that change happens: the worker (start, progress, end), or the API (a queued
job canceled, a lost worker's job reaped). So no event is lost or sent for a change that did not happen,
and the worker's only cost is one more write in a transaction it makes anyway; the HTTP calls happen in the
API processes' deliverer, never in a worker.

Deliveries follow the Standard Webhooks scheme (https://www.standardwebhooks.com): headers ``webhook-id``
(the same for every retry of one event), ``webhook-timestamp`` (the attempt, Unix seconds) and
``webhook-signature: v1,<base64 HMAC-SHA256 of "{id}.{timestamp}.{body}">`` with the deployment's secret
(``CTP_WEBHOOK_SECRET``, ``whsec_`` and base64).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import ipaddress
import socket
import time
import uuid
from typing import Literal, get_args
from urllib.parse import urlsplit

from pydantic import BaseModel, Field
from redis import Redis

Event = Literal["start", "progress", "completed"]
EVENTS: tuple[str, ...] = get_args(Event)
DEFAULT_EVENTS: tuple[str, ...] = ("completed",)
PROGRESS_EVERY_S = 1.0  # at most one progress event a second per job
URL_MAX = 2048
_NAT64 = ipaddress.ip_network("64:ff9b::/96")


class Webhook(BaseModel):
    """A job's webhook: where it goes, which events, and how its deliveries went so far."""

    url: str = Field(description="where deliveries are POSTed")
    events: list[Event] = Field(description="the events subscribed to: start, progress (at most one a second), "
                                "completed (succeeded, failed or canceled)")
    delivered: int = Field(0, description="events delivered (the receiver answered 2xx)")
    failed: int = Field(0, description="events given up: progress after its one attempt, the others after "
                        "retrying for CTP_WEBHOOK_RETRY_S")
    pending: int = Field(0, description="events not yet delivered nor given up (queued, or waiting for a retry)")
    attempts: int = Field(0, description="HTTP attempts made, retries included")
    last_status: int | None = Field(None, description="HTTP status of the last attempt; null before the first "
                                    "or when it got no answer")
    last_error: str | None = Field(None, description="why the last attempt failed (no answer, a non-2xx status, "
                                   "a refused address); null after a delivery")


class WebhookInvalid(Exception):
    """A webhook URL that cannot be called (code ``invalid_webhook``) or may not be (``webhook_url_refused``)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code, self.message = code, message


# -- signing ----------------------------------------------------------------------------------------
def secret_bytes(secret: str) -> bytes:
    """The HMAC key of a Standard Webhooks secret (``whsec_`` + base64); ValueError when it is not one."""
    if not secret.startswith("whsec_"):
        raise ValueError("a webhook secret starts with whsec_ (then base64)")
    key = base64.b64decode(secret.removeprefix("whsec_"), validate=True)
    if len(key) < 16:
        raise ValueError("a webhook secret holds at least 16 bytes")
    return key


def signature(key: bytes, msg_id: str, timestamp: int, body: bytes) -> str:
    """The ``webhook-signature`` header value."""
    mac = hmac.new(key, f"{msg_id}.{timestamp}.".encode() + body, hashlib.sha256).digest()
    return "v1," + base64.b64encode(mac).decode()


# -- where a webhook may go -------------------------------------------------------------------------
def check_url(url: str) -> tuple[str, int]:
    """An http(s) URL with a host (``invalid_webhook`` otherwise); returns its host and port."""
    if len(url) > URL_MAX:
        raise WebhookInvalid("invalid_webhook", f"the webhook URL is over {URL_MAX} characters")
    if any(ord(c) <= 32 or ord(c) == 127 for c in url):
        raise WebhookInvalid("invalid_webhook", "the webhook URL holds spaces or control characters")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise WebhookInvalid("invalid_webhook", f"the webhook URL is malformed: {exc}") from None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise WebhookInvalid("invalid_webhook", "the webhook URL must be http:// or https:// with a host")
    return parts.hostname, port or (443 if parts.scheme == "https" else 80)


def _refused(address: ipaddress.IPv4Address | ipaddress.IPv6Address) -> bool:
    """Loopback, private, link-local, shared, reserved, unspecified or multicast: not the public internet. An
    IPv6 address that carries an IPv4 one (mapped, NAT64, 6to4) is judged by that one."""
    if isinstance(address, ipaddress.IPv6Address):
        inner = address.ipv4_mapped or address.sixtofour
        if inner is None and address in _NAT64:
            inner = ipaddress.IPv4Address(int(address) & 0xFFFFFFFF)
        if inner is not None:
            return _refused(inner)
    return not address.is_global or address.is_multicast


def resolve(host: str, port: int, allow_private: bool) -> list[str]:
    """The addresses to call ``host`` at; ``webhook_url_refused`` when any is not public (unless
    ``allow_private``), ``invalid_webhook`` when the name does not resolve. Blocking (DNS)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError) as exc:
        raise WebhookInvalid("invalid_webhook", f"the webhook host {host!r} does not resolve: {exc}") from None
    addresses = list(dict.fromkeys(str(info[4][0]).split("%")[0] for info in infos))
    if not allow_private:
        for address in addresses:
            if _refused(ipaddress.ip_address(address)):
                raise WebhookInvalid("webhook_url_refused", f"the webhook host {host!r} resolves to {address}, "
                                     "which is not a public address (loopback, private, link-local, multicast or "
                                     "reserved); this service calls public addresses only")
    return addresses


# -- the outbox -------------------------------------------------------------------------------------
class Delivery(BaseModel):
    """One event to deliver, as the outbox holds it: the job as it was when the event happened."""

    id: str
    job_id: str
    event: Event
    url: str
    created: float = Field(description="when the event happened (Unix seconds)")
    attempts: int = 0
    record: str = Field(description="the job record (JSON) right after the change")


# Atomically: the due deliveries, each hidden for hold_s (a deliverer that dies mid-attempt lets it reappear).
_CLAIM = """
local due = redis.call('ZRANGEBYSCORE', KEYS[1], '-inf', ARGV[1], 'LIMIT', 0, tonumber(ARGV[3]))
for _, member in ipairs(due) do redis.call('ZADD', KEYS[1], ARGV[2], member) end
return due
"""


class Outbox:
    """Deliveries waiting in Redis: ``{prefix}:webhooks`` (a sorted set of ids by when they are due) and
    ``{prefix}:webhook:{id}`` (each one's ``Delivery``, kept as long as a job)."""

    def __init__(self, redis: Redis, prefix: str, ttl_s: int):
        self.redis, self.prefix, self.ttl_s = redis, prefix, ttl_s
        self._claim = redis.register_script(_CLAIM)

    @property
    def _due_key(self) -> str:
        return f"{self.prefix}:webhooks"

    def _key(self, delivery_id: str) -> str:
        return f"{self.prefix}:webhook:{delivery_id}"

    def add(self, pipe, job_id: str, event: str, url: str, record: str) -> None:
        """Queue an event, on the caller's transaction (the one that changes the job)."""
        delivery = Delivery(id=f"msg_{uuid.uuid4().hex}", job_id=job_id, event=event, url=url, created=time.time(),
                            record=record)
        pipe.set(self._key(delivery.id), delivery.model_dump_json(), ex=self.ttl_s)
        pipe.zadd(self._due_key, {delivery.id: delivery.created})

    def claim(self, limit: int, hold_s: float) -> list[Delivery]:
        """Up to ``limit`` due deliveries, hidden from other deliverers for ``hold_s``; an id whose data has
        expired is dropped."""
        now = time.time()
        ids = [raw.decode() for raw in self._claim(keys=[self._due_key], args=[now, now + hold_s, limit])]
        if not ids:
            return []
        raws = self.redis.mget([self._key(i) for i in ids])
        gone = [i for i, raw in zip(ids, raws, strict=True) if raw is None]
        if gone:
            self.redis.zrem(self._due_key, *gone)
        return [Delivery.model_validate_json(raw) for raw in raws if raw is not None]

    def settle(self, pipe, delivery: Delivery, retry_at: float | None) -> None:
        """After an attempt, on the caller's transaction (the one that counts it in the job, ``Jobs.delivery_done``):
        due again at ``retry_at``, or gone (None: delivered or given up)."""
        if retry_at is None:
            pipe.zrem(self._due_key, delivery.id)
            pipe.delete(self._key(delivery.id))
        else:
            pipe.set(self._key(delivery.id), delivery.model_dump_json(), ex=self.ttl_s)
            pipe.zadd(self._due_key, {delivery.id: retry_at})
