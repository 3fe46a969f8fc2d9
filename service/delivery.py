"""The webhook deliverer: a thread of each API process that takes due events from the outbox
(``service.webhooks.Outbox``) and POSTs them, signed, to their URLs, a few at a time.

Why here: events arise in workers and in the API (a queued job canceled, a lost worker's job reaped), and
the outbox in Redis carries them all to one place; delivering from the API keeps every HTTP call, its
timeouts and its retries out of the workers, whose only cost is the outbox write in a transaction they make
anyway, so a job never waits on a receiver. Several API processes share the work: a claim hides an event
from the others for a while (``Outbox.claim``), and one whose deliverer died reappears after that. Delivery is
at least once; receivers deduplicate by ``webhook-id``.

Each attempt re-resolves the host, refuses a non-public address unless allowed (the submit-time check
does not cover a name that now resolves elsewhere) and connects to the address it checked, not to a second
resolution; redirects are not followed and proxy variables are ignored. Start and completed events are
retried with exponential back-off (1 s doubling to 5 min) until ``CTP_WEBHOOK_RETRY_S`` after the event; a
progress event is tried once (the next one, at most a second later, supersedes it).
"""

from __future__ import annotations

import logging
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime

import httpx
from redis.exceptions import RedisError

from service.jobs import JobRecord, Jobs
from service.schemas import JobOut, WebhookPayload
from service.webhooks import Delivery, WebhookInvalid, check_url, resolve, signature

log = logging.getLogger("ctp.service")

IN_FLIGHT = 8  # concurrent attempts per API process
POLL_S = 0.2  # how often the outbox is looked at
BACKOFF_FIRST_S, BACKOFF_MAX_S = 1.0, 300.0


class Deliverer(threading.Thread):
    """Delivers the outbox's due events until ``stop``."""

    def __init__(self, jobs: Jobs, key: bytes, *, allow_private: bool, retry_s: float, timeout_s: float):
        super().__init__(name="ctp-webhooks", daemon=True)
        self.jobs, self.key, self.allow_private, self.retry_s = jobs, key, allow_private, retry_s
        self.hold_s = 4 * timeout_s + 10  # longer than one attempt can take: connect, write, read
        # No kept-alive connections: one is pinned to a checked address and, for https, to the host name its
        # certificate was checked against, so it must not carry another webhook's request.
        self.http = httpx.Client(follow_redirects=False, trust_env=False, timeout=timeout_s,
                                 limits=httpx.Limits(max_keepalive_connections=0),
                                 headers={"user-agent": "ctp-webhooks"})
        self.pool = ThreadPoolExecutor(IN_FLIGHT, thread_name_prefix="ctp-webhook")
        self._stop_event = threading.Event()
        self._lock = threading.Lock()
        self._busy = 0

    def run(self) -> None:
        while not self._stop_event.wait(POLL_S):
            with self._lock:
                free = IN_FLIGHT - self._busy
            if free <= 0:
                continue
            try:
                due = self.jobs.outbox.claim(free, self.hold_s)
            except RedisError as exc:
                log.warning("webhooks: redis unavailable: %s", exc)
                continue
            for delivery in due:
                with self._lock:
                    self._busy += 1
                self.pool.submit(self._attempt, delivery)

    def stop(self) -> None:
        """Stop taking events; attempts under way finish (those not begun reappear for another process)."""
        self._stop_event.set()
        self.join(timeout=POLL_S + 1)
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.http.close()

    def _attempt(self, delivery: Delivery) -> None:
        try:
            body = WebhookPayload(type=delivery.event, timestamp=datetime.fromtimestamp(delivery.created, UTC),
                                  data=JobOut.of(JobRecord.model_validate_json(delivery.record)))
            status, error = self._post(delivery, body.model_dump_json().encode())
            delivery.attempts += 1
            delivered = status is not None and 200 <= status < 300
            next_at = time.time() + min(BACKOFF_MAX_S, BACKOFF_FIRST_S * 2 ** (delivery.attempts - 1))
            final = delivered or delivery.event == "progress" or next_at > delivery.created + self.retry_s
            self.jobs.delivery_done(delivery, delivered=delivered, retry_at=None if final else next_at,
                                    status=status, error=error)
            outcome = "delivered" if delivered else "given up" if final else "failed, will retry"
            log.log(logging.DEBUG if delivered else logging.WARNING, "webhook %s event %s (attempt %d)%s",
                    delivery.event, outcome, delivery.attempts, f": {error}" if error else "",
                    extra={"job_id": delivery.job_id, "http_status": status})
        except Exception:  # the claim lapses and the event is tried again
            log.exception("webhook delivery crashed", extra={"job_id": delivery.job_id})
        finally:
            with self._lock:
                self._busy -= 1

    def _post(self, delivery: Delivery, body: bytes) -> tuple[int | None, str | None]:
        """One attempt: (HTTP status or None, why it failed or None)."""
        url = httpx.URL(delivery.url)
        try:
            host, port = check_url(delivery.url)
            address = resolve(host, port, self.allow_private)[0]
        except WebhookInvalid as exc:
            return None, exc.message
        timestamp = int(time.time())
        headers = {"content-type": "application/json", "host": url.netloc.decode("ascii"),
                   "webhook-id": delivery.id, "webhook-timestamp": str(timestamp),
                   "webhook-signature": signature(self.key, delivery.id, timestamp, body)}
        # The checked address, not a second resolution; TLS still checks the certificate against the host name.
        extensions = {"sni_hostname": host} if url.scheme == "https" else {}
        try:
            with self.http.stream("POST", url.copy_with(host=address), content=body, headers=headers,
                                  extensions=extensions) as answer:
                status = answer.status_code
        except httpx.HTTPError as exc:
            return None, f"no answer: {type(exc).__name__}: {exc}"[:300]
        if 200 <= status < 300:
            return status, None
        return status, f"answered {status}" + (" (redirects are not followed)" if 300 <= status < 400 else "")
