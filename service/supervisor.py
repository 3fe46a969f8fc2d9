"""Supervision of what ``ctp serve`` starts in embedded mode: its worker processes and its Redis.

A thread polls them every ``POLL_S``. A worker that exited (killed, crashed, lost its Redis) is
started again after a back-off that doubles from ``BACKOFF_S`` to ``BACKOFF_MAX_S`` while it keeps
dying and resets once one has lived ``STABLE_S``; the job it was running is queued again (once) by
the API's reaper, and jobs submitted meanwhile are accepted and queued (the "last seen" grace,
``service.jobs``). A redis-server that exited is started again on the same port with the
same data directory, so the append-only file brings back every queued job (``appendfsync
everysec``: a hard kill may lose the last second of writes). Each restart is logged. In the compose
layout, restart policies do the same (``docker/compose.yaml``).
"""

from __future__ import annotations

import logging
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from service.embedded import EmbeddedRedis

log = logging.getLogger("ctp.serve")

POLL_S = 0.5
BACKOFF_S = 1.0
BACKOFF_MAX_S = 30.0
STABLE_S = 60.0


@dataclass
class _Child:
    """One supervised process and its restart state."""

    name: str
    start: Callable[[], None]
    process: Callable[[], subprocess.Popen | None]  # the current one; None before the first start
    started_at: float = 0.0
    first_backoff_s: float = BACKOFF_S
    backoff_s: float = BACKOFF_S
    restart_at: float | None = None
    restarts: int = 0

    def running(self) -> bool:
        process = self.process()
        return process is not None and process.poll() is None

    def exit_code(self) -> int | None:
        process = self.process()
        return None if process is None else process.poll()


class Supervisor:
    """Keeps ``workers`` worker processes (started by ``spawn``) and the embedded Redis, if any, running.
    ``worker_backoff_s``: a worker's first back-off (``BACKOFF_S``; a test lengthens it to hold a restart open)."""

    def __init__(self, spawn: Callable[[], subprocess.Popen], workers: int, redis: EmbeddedRedis | None = None,
                 *, worker_backoff_s: float = BACKOFF_S):
        self.spawn = spawn
        self.processes: list[subprocess.Popen | None] = [None] * workers
        self._stop = threading.Event()
        self._children: list[_Child] = []
        if redis is not None:
            self._children.append(_Child("redis-server", lambda: redis.start(), lambda: redis.process,
                                         started_at=time.monotonic()))
        for slot in range(workers):
            self._children.append(_Child(f"worker {slot + 1}", self._starter(slot),
                                         lambda slot=slot: self.processes[slot], first_backoff_s=worker_backoff_s,
                                         backoff_s=worker_backoff_s))
        self._thread = threading.Thread(target=self._run, name="ctp-supervisor", daemon=True)

    def start(self) -> Supervisor:
        """Start the workers, then watch everything until ``stop``."""
        for child in self._children:
            if child.name.startswith("worker"):
                child.start()
                child.started_at = time.monotonic()
        self._thread.start()
        return self

    def stop(self) -> list[subprocess.Popen]:
        """Stop watching (nothing is restarted after this returns); the worker processes, to be stopped."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        return [p for p in self.processes if p is not None]

    def _starter(self, slot: int) -> Callable[[], None]:
        def start() -> None:
            self.processes[slot] = self.spawn()
        return start

    def _run(self) -> None:
        while not self._stop.wait(POLL_S):
            # Redis first: a worker restarted before its Redis is back would only die again.
            for child in self._children:
                try:
                    self._tend(child)
                except Exception:  # never let the supervisor die: log, and try again next round
                    log.exception("supervisor: restarting %s failed", child.name)
                    child.restart_at = time.monotonic() + child.backoff_s
                    child.backoff_s = min(2 * child.backoff_s, BACKOFF_MAX_S)

    def _tend(self, child: _Child) -> None:
        now = time.monotonic()
        if child.running():
            if now - child.started_at > STABLE_S:
                child.backoff_s = child.first_backoff_s
            return
        if child.restart_at is None:  # just found dead
            child.restart_at = now + child.backoff_s
            child.backoff_s = min(2 * child.backoff_s, BACKOFF_MAX_S)
            log.warning("supervisor: %s exited (status %s); restarting in %.0f s", child.name, child.exit_code(),
                        child.restart_at - now)
        if now < child.restart_at or self._stop.is_set():
            return
        child.start()
        child.started_at, child.restart_at = time.monotonic(), None
        child.restarts += 1
        log.warning("supervisor: %s restarted (restart %d)", child.name, child.restarts)
