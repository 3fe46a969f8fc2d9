"""A worker rides out a Redis outage (a restart, a failover) instead of losing its running job.

Every Redis client of a worker (its job store, rq's connection) retries a command that finds Redis gone, with a
back-off that doubles from ``BACKOFF_BASE_S`` to ``BACKOFF_CAP_S``, so it reconnects within half a second of Redis
answering again. Meanwhile the worker's calls wait: the running job pauses at its next progress write or step check
and keeps everything it computed; its progress and result are written when Redis is back, and its leases are
renewed, also one that lapsed meanwhile (``Jobs.heartbeat``; the API's reaper waits one lease after an outage).
One outage is one JSON log line, when it ends.

The wait is bounded by ``CTP_REDIS_PATIENCE_S``: past it the worker logs one line and exits with status 1, so that
an outage that is no blip shows as a worker restart (supervisor, orchestrator) rather than a silent hang; a job it
was running is then reaped when Redis is back and run again once (``service.jobs``). The exit is a ``SystemExit``
raised from every call that finds Redis still gone: rq's loop and the job's own error handling let it through, it
ends the process without a traceback, and a thread it ends, silently.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from redis import Redis
from redis.backoff import ExponentialBackoff
from redis.retry import Retry

log = logging.getLogger("ctp.worker")

BACKOFF_BASE_S = 0.05
BACKOFF_CAP_S = 0.5
CONNECT_TIMEOUT_S = 5.0  # a Redis host that vanished (no refusal) costs this per attempt, not the OS's minutes


class Outage:
    """The process's one view of its Redis outage, shared by every client and thread: since when Redis has not
    answered, and how long to wait for it."""

    def __init__(self, patience_s: float = 60.0):
        self.patience_s = patience_s
        self.worker: str | None = None  # named in the log lines
        self._lock = threading.Lock()
        self._since: float | None = None
        self._gave_up = False

    def failed(self, error: Exception) -> bool:
        """A command found Redis gone: retry it (True), or raise ``SystemExit(1)`` once the outage outlasted the
        patience (exactly ``SystemExit``: Python's thread hook reports a subclass with its traceback)."""
        with self._lock:
            now = time.monotonic()
            if self._since is None:
                self._since = now
            down_s, first = now - self._since, not self._gave_up
            if down_s > self.patience_s:
                self._gave_up = True
        if down_s <= self.patience_s:
            return True
        if first:
            log.error("redis unreachable for %.1f s (%s): giving up (CTP_REDIS_PATIENCE_S %.0f s); the worker exits",
                      down_s, error, self.patience_s, extra={"worker": self.worker})
        raise SystemExit(1)

    def retried(self) -> None:
        """A command that failed got its answer on a new connection: the outage, if any, is over (logged once).
        Only such a one tells: a command that did not fail may have been answered before Redis went away, or may
        not have needed it (redis-py "connects" a pooled connection whose socket it has not yet found dead)."""
        if self._since is None:
            return
        with self._lock:
            since = self._since
            if since is None:
                return
            self._since = None
        log.warning("redis was unreachable for %.1f s; reconnected, work in progress kept", time.monotonic() - since,
                    extra={"worker": self.worker})


OUTAGE = Outage()


def _retryable(error: Exception) -> bool:
    return OUTAGE.failed(error)


class _Patient(Retry):
    """redis-py's retry, which tells ``OUTAGE`` when a command that failed got its answer (the end of an outage)."""

    def call_with_retry(self, do, fail, is_retryable=None, with_failure_count: bool = False) -> Any:
        failures = []

        def failed(*args: Any) -> Any:
            failures.append(args[0])
            return fail(*args)

        result = super().call_with_retry(do, failed, is_retryable, with_failure_count)
        if failures:
            OUTAGE.retried()
        return result


def patient_redis(url: str, patience_s: float, **options: Any) -> Redis:
    """A client of the Redis at ``url`` that waits out an outage of up to ``patience_s`` (see the module)."""
    OUTAGE.patience_s = patience_s
    retry = _Patient(ExponentialBackoff(cap=BACKOFF_CAP_S, base=BACKOFF_BASE_S), -1, is_retryable=_retryable)
    return Redis.from_url(url, retry=retry, socket_connect_timeout=CONNECT_TIMEOUT_S, **options)
