"""One worker process: an rq ``SimpleWorker`` on the named queues it serves (``CTP_QUEUES``) plus a heartbeat
thread. It needs only the Redis URL and the storage settings: nothing on its disk is shared with the API.

``SimpleWorker`` runs jobs in this process instead of forking a child per job, so the vision-language
model loaded at start-up (``loaders.get_guide`` caches it per process) serves every job, and torch
never has to survive a fork. The heartbeat thread keeps this worker visible to ``/readyz`` with its
queues and the models it can run (checked once at start: the default loaded, the others' weights looked for;
a "last seen" record keeps them counted for ``CTP_WORKER_GRACE_S`` after the worker dies or exits, so jobs
are still accepted while it is restarted, ``service.jobs``), holds the lease of the running job (lapsed
lease: the API's reaper queues the job again, once, then fails it ``worker_lost``) and republishes progress
when the optimiser has been quiet for a while.

Its Redis clients wait out a Redis outage (``worker.outage``). A stop signal (SIGTERM or SIGINT, the first or any
later one) is always a warm stop: the running job is handed back at its next step, queued again for another worker
(``Jobs.hand_back``), or finishes first if it gets there sooner; the worker then leaves. The stop flag is set before
anything is torn down, and whatever error ends a job after it is the stop's, not the job's (``worker.stop``).
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any

from redis.exceptions import RedisError
from rq import SimpleWorker
from rq.serializers import JSONSerializer
from rq.utils import now as utcnow

from ctp_core.io.loader import MeshLoader
from service import logs
from service.jobs import Jobs, Progress
from service.settings import Settings
from worker.outage import OUTAGE, patient_redis
from worker.stop import Stop

log = logging.getLogger("ctp.worker")


class Heartbeat(threading.Thread):
    """Refresh this worker's and its job's leases; keep a running job's progress fresh."""

    def __init__(self, jobs: Jobs, name: str, period_s: float, progress_every_s: float,
                 models: dict[str, str | None] | None = None, queues: list[str] | None = None):
        super().__init__(name="ctp-heartbeat", daemon=True)
        self.jobs, self.worker, self.period_s, self.progress_every_s = jobs, name, period_s, progress_every_s
        self.models, self.queues = models or {}, queues
        self._stop_event = threading.Event()
        self._lock = threading.Lock()
        self.job_id: str | None = None
        self._progress: Progress | None = None
        self._job_started = self._published = self._event_at = 0.0  # monotonic: job start, last write, last event

    def run(self) -> None:
        while not self._stop_event.is_set():
            try:
                self.jobs.heartbeat(self.worker, self.job_id, self.models, self.queues, self.period_s)
                self._refresh_progress()
            except RedisError as exc:  # not an outage (those are waited out, worker.outage): beat again
                log.warning("heartbeat failed: %s", exc, extra={"worker": self.worker})
            except Exception:  # never let the thread die: a silent worker has its jobs reaped
                log.exception("heartbeat error", extra={"worker": self.worker, "job_id": self.job_id})
            self._stop_event.wait(self.period_s)

    def stop(self) -> None:
        self._stop_event.set()
        self.join(timeout=self.period_s + 1)

    def begin(self, job_id: str) -> None:
        with self._lock:
            self.job_id, self._progress = job_id, None
            self._job_started = self._published = time.monotonic()

    def end(self) -> None:
        with self._lock:
            self.job_id, self._progress = None, None

    def publish(self, progress: Progress, *, force: bool = False, min_interval_s: float = 0.5) -> None:
        """Store a progress update (``elapsed_s`` counted from the job's start); step events are thinned
        to one per ``min_interval_s``."""
        with self._lock:
            job_id, now = self.job_id, time.monotonic()
            if job_id is None:
                return
            self._progress, self._event_at = progress, now
            if force or now - self._published >= min_interval_s:
                self._write(job_id, progress, now)

    def _refresh_progress(self) -> None:
        """Republish the last progress with elapsed and ETA moved on, when nothing was written lately."""
        with self._lock:
            job_id, progress, now = self.job_id, self._progress, time.monotonic()
            if job_id is not None and progress is not None and now - self._published >= self.progress_every_s:
                self._write(job_id, progress, now)

    def _write(self, job_id: str, progress: Progress, now: float) -> None:
        # Under the lock: writes from the job thread and this thread never reorder.
        eta = None if progress.eta_s is None else max(0.0, round(progress.eta_s - (now - self._event_at), 1))
        self.jobs.set_progress(job_id, progress.model_copy(update={"elapsed_s": round(now - self._job_started, 3),
                                                                   "eta_s": eta}), self.worker)
        self._published = now


@dataclass
class WorkerContext:
    settings: Settings
    jobs: Jobs
    name: str
    beat: Heartbeat
    loader: MeshLoader
    stop: Stop  # requested by a stop signal: the running job is handed back at its next step


_CONTEXT: WorkerContext | None = None


def context() -> WorkerContext:
    """This process's worker state (set by ``run_worker``)."""
    if _CONTEXT is None:
        raise RuntimeError("worker.tasks.run_job runs inside `ctp worker` (worker.main.run_worker)")
    return _CONTEXT


def run_worker(settings: Settings, stop: Stop, *, burst: bool = False, name: str | None = None) -> int:
    """Preload the default model, then take jobs until stopped (SIGTERM/SIGINT: after the current job). ``stop``: the
    process's stop, listening since before the engine's imports (``Stop.listening``: ``ctp worker``); a stop during
    start-up leaves before any job is taken, with status 128 + the signal."""
    global _CONTEXT
    logs.configure(settings.log_level)
    name = name or f"{socket.gethostname()}.{os.getpid()}"
    OUTAGE.worker = name
    jobs = Jobs.from_settings(settings, patient_redis(settings.redis_url, settings.redis_patience_s,
                                                      health_check_interval=30))
    models = _preload(settings)
    if stop.requested:  # a stop whose exit an import swallowed (``Stop.listening``)
        return stop.exit_status
    queues = settings.served_queues
    beat = Heartbeat(jobs, name, settings.heartbeat_s, settings.progress_every_s, models, queues)
    loader = settings.mesh_loader(processes=1)
    _CONTEXT = WorkerContext(settings, jobs, name, beat, loader, stop)
    beat.start()
    # rq gets a connection of its own: it raises the socket timeout above its blocking dequeue, which the
    # heartbeat thread's connections (redis-py's default timeout) must not share.
    # Listed first, taken first: a worker serving "gpu,cpu" empties its gpu queue before taking a cpu job.
    worker = _Worker([jobs.rq_queue(q).name for q in queues],
                     connection=patient_redis(settings.redis_url, settings.redis_patience_s),
                     serializer=JSONSerializer, name=name)
    worker.stop = stop
    log.info("worker ready", extra={"worker": name, "queues": queues})
    try:
        worker.work(burst=burst, logging_level=settings.log_level.upper())
    finally:
        beat.stop()
        loader.close()
        jobs.workers.gone(name)
        _CONTEXT = None
    return 0


class _Worker(SimpleWorker):
    """rq's in-process worker, whose every stop signal is a warm stop that hands the running job back: rq's own
    makes a second signal a cold stop, which would kill the job mid-run and leave it to be reaped."""

    stop: Stop

    def request_stop(self, signum, frame) -> None:
        if not self.stop.request(signum):  # under way: a later signal changes nothing
            return
        log.info("stop requested (%s): the running job, if any, is handed back", signal.Signals(signum).name,
                 extra={"worker": self.name})
        self._shutdown_requested_date = utcnow()
        self._shutdown()  # idle: stop now; busy: once the job returns

    def unsubscribe(self) -> None:
        """rq's, with a bounded wait for redis-py's pubsub thread, whose ``stop`` waits for the thread: after the
        unsubscribe it may sleep out its whole period (60 s) before it looks at its flag, which held a stopping worker
        that long. It is a daemon thread: the process leaves without it."""
        if self.pubsub_thread:
            self.pubsub.unsubscribe()
            self.pubsub_thread.stop(timeout=1)
            self.pubsub.close()


def where(settings: Settings) -> dict[str, Any]:
    """Where this worker runs a job (device, threads, forward-only runtime): the only parts of a validated
    config that are the worker's to decide (``worker.tasks.served`` applies them to a job and refuses the
    job when they cannot serve it)."""
    return {"device": settings.device, "threads": settings.threads, "runtime": settings.runtime}


def _preload(settings: Settings) -> dict[str, str | None]:
    """Load the default model once for the life of the process and look for the weights of the other
    models the service allows; returns ``{spec: None when this worker can run it, else why not}``, which
    the heartbeat publishes so that the API refuses jobs no worker can run (``Jobs.unavailable``). Under
    ``auto`` every worker runs the default jobs (with or without a guide), and what it loads is what auto picks
    now (``selection.choose``; each job chooses again as it is taken)."""
    import torch

    from ctp_core.config import AUTO, AlignConfig
    from ctp_core.errors import ModelError
    from ctp_core.guide import checkpoints, selection
    from ctp_core.guide.loaders import guide_for

    if settings.threads:
        torch.set_num_threads(settings.threads)
    started = time.perf_counter()
    models = {spec: checkpoints.missing(spec) for spec in settings.allowed_models}
    # auto runs every job (without a guide where the default model is missing): preload what it picks now
    choice = selection.choose() if settings.model == AUTO else None
    preload = choice.guide if choice else settings.model
    if choice and preload == selection.NONE:
        log.warning("no guide: %s (%s)", choice.why, choice.get_model)
        return models
    # The guide of a job with default options on this worker (the same cache entry its jobs get). Built
    # unvalidated: the guide depends only on these fields, and a forward-only default model refuses the
    # configuration's class defaults (which descend the guide), options it would never be asked to run.
    default_job = AlignConfig.model_construct(model=preload, **where(settings))
    try:
        guide = guide_for(default_job)
    except ModelError as exc:
        log.error("default model unavailable: %s", exc.message)
        models[preload] = exc.message
    else:
        log.info("model %s loaded in %.1f s (forward-only runtime %s)", preload, time.perf_counter() - started,
                 guide.runtime)
        models[preload] = None
    return models
