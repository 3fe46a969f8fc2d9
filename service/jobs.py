"""Job records and their life cycle in Redis: the one place that changes a job's status.

A job is a JSON record ``{prefix}:job:{id}`` (status, progress, timestamps, error, the validated
config) plus its blobs in ``storage``. rq carries only the job id (JSON serializer), so a worker never
deserialises anything a client sent except through ``ctp_core.io``. Every change goes through
``Jobs._update`` (WATCH/MULTI compare-and-set) and is published on ``{prefix}:events:{id}`` for the
server-sent events stream, so the API, the workers and the reaper can race without losing a transition:

    queued -> running -> succeeded | failed | canceled
    queued -> canceled                      (DELETE before a worker picks it up)

A record is written ``queued`` only in the transaction that puts its rq job on the queue (``submit``, ``_requeue``,
``enqueue_again``), noted in the index of queued jobs (``queued_key``) that the reconciler reads
(``service.reconcile``): no crash leaves a queued record without its place in the queue for long.

A change that is an event the job's webhook subscribes to (start, progress at most once a second, completed)
also queues a delivery in the webhook outbox, in the same transaction (``service.webhooks``).

Liveness: a running job holds a lease key ``{prefix}:lease:{id}`` that its worker refreshes every
heartbeat. ``reap`` finds running jobs whose lease lapsed (worker SIGKILLed, machine gone, frozen; a lease that
lapsed in a Redis outage is renewed by the worker's next heartbeat, and the API's reaper waits one lease after an
outage, ``service.app``): such a job is queued again, once (``MAX_ATTEMPTS``, counted in ``attempts``), and then
fails ``worker_lost``. Once, because a job that itself kills its worker would otherwise take every worker down
in turn; a job that outgrows its memory does not kill its worker (the ceiling fails it ``job_too_large``), so a
lost worker is more often a machine's or an operator's doing than the job's. A stopping worker hands its job
back (``hand_back``): queued again, the attempt not counted. A worker that was only frozen finds its job no
longer its own and stops (``should_stop``); its late writes are refused.

Queues: a job goes to one named queue (its ``queue``, default the deployment's), the rq queue
``{prefix}:{queue}``; a worker takes jobs from the queues it serves (``CTP_QUEUES``), so GPU and CPU
workers can share one deployment.

Workers: which are alive, which were seen within the grace and what each offers is ``service.workers``
(``Jobs.workers``); a job's readiness is judged on it (``unavailable``).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import math
import time
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any, Literal, TypeVar

from pydantic import BaseModel, Field
from redis import Redis, WatchError
from rq import Queue
from rq.exceptions import InvalidJobOperation, NoSuchJobError
from rq.job import Job as RqJob
from rq.serializers import JSONSerializer

from ctp_core.config import AlignConfig
from service import faults
from service.settings import DEFAULT_QUEUE
from service.storage import Storage, StorageUnavailable, open_storage
from service.webhooks import PROGRESS_EVERY_S, Delivery, Outbox, Webhook
from service.workers import Offer, SeenWorker, Workers, served_queues, serving

if TYPE_CHECKING:
    from redis.asyncio import Redis as AsyncRedis

    from service.settings import Settings

M = TypeVar("M", bound=BaseModel)  # ``compare_and_set``: the record model

log = logging.getLogger("ctp.service")

Status = Literal["queued", "running", "succeeded", "failed", "canceled"]
TERMINAL: frozenset[str] = frozenset({"succeeded", "failed", "canceled"})
INPUTS = ("target", "source", "image")  # an assembly's are "target" (its base), "source-<i>", "image-<i>"
# Result files: name -> media type.
OUTPUTS = {"result.glb": "model/gltf-binary", "report.json": "application/json", "preview.png": "image/png",
           "alternatives.png": "image/png"}
ORIGINAL = "original.glb"  # once an adjustment is saved (``service.adjustments``): the run's own result.glb, kept


def alternative_blob(k: int) -> str:
    """The stored name of alternative ``k``'s GLB (``result.glb?alternative=k``): the answer's is ``result.glb``."""
    return "result.glb" if k == 0 else f"alternative-{k}.glb"


class Alternative(BaseModel):
    """One of the best distinct placements a job refined (the report's ``alternatives`` has them whole)."""

    index: int = Field(description="0 for the answer, then the next best distinct ones: ?alternative=index")
    objective: float = Field(description="its objective on the evaluation views (lower is better)")
    guide_match: float | None = Field(None, description="mean cosine between its views and the goal; null "
                                      "without a guide")
    relation_holds: bool | None = Field(None, description="whether the prompt's relation holds there; null "
                                        "without one")


class SavedAdjustment(BaseModel):
    """A saved adjustment (``POST /jobs/{id}/adjust`` with ``save``): ``result.glb`` and ``report.json`` hold the
    adjusted scene, ``original.glb`` the run's own answer."""

    saved_at: datetime = Field(description="when it was saved (UTC)")
    adjustment: str = Field(description="the adjustment that saved it (GET /jobs/{id}/adjust/{adjustment})")
    transform: list[list[float]] = Field(description="the source's 4x4 now, source file -> target file, row-major")
    penetration: float = Field(description="penetration into the target over the source's diagonal, there")
    contact_gap: float = Field(description="gap to the target in source diagonals, there (0: touching)")


TASK = "worker.tasks.run_job"  # by name: the API never imports the engine
MAX_ATTEMPTS = 2  # a job whose worker was lost is run once more (``Jobs.reap``)
# A running job's lease, renewed while the job is still running (in the running set): also after it lapsed during a
# Redis outage longer than the lease (Redis keeps expiry times across a restart), never for a job that ended or
# was reaped.
_RENEW_LEASE = """
if redis.call('sismember', KEYS[2], ARGV[1]) == 1 then
    redis.call('set', KEYS[1], ARGV[2], 'EX', ARGV[3])
end
return 0
"""


class ClaimLost(Exception):
    """A submit's ``Idempotency-Key`` claim lapsed (its request was stalled past the claim's hold) and another request
    holds it now: this one creates no job (``service.submit``)."""


class TooManyJobs(Exception):
    """The key already has its limit of queued plus running jobs; ``retry_after_s``: when to ask again."""

    def __init__(self, message: str, retry_after_s: int):
        super().__init__(message)
        self.retry_after_s = retry_after_s


# 429's Retry-After bounds (s): an estimate under a second is rounded up to one; the upper bound is what a client
# waits when none of the key's jobs has an estimate yet (all queued, or loading): about the first minute of a job.
SLOT_RETRY_S = (1, 60)

class Stage(BaseModel):
    """Which part of the pipeline runs now, and which alignment of the job (an assembly places several)."""

    name: str = Field("queued", description="pipeline stage: queued, loading, model, search (step/steps count "
                      "candidate poses scored), refine (step/steps count optimisation steps), exporting, done")
    index: int = Field(1, ge=1, description="1-based alignment of this job (an assembly places one object each, a "
                       "job of several copies one copy each)")
    count: int = Field(1, ge=1, description="alignments in this job (1 for POST /align of one source)")
    label: str = Field("", description="what the current alignment places (an assembly step's prompt, a copy's "
                       "name)")


class Progress(BaseModel):
    """Where a job is; the optimiser's ProgressEvent, flattened for clients."""

    stage: Stage = Field(default_factory=Stage, description="the pipeline stage and, for an assembly, which "
                         "object is being placed")

    kind: str = Field("queued", description="queued, loading, model, phase_start, step, phase_end, "
                      "exporting or done")
    phase: int = Field(0, description="1-based optimisation phase; 0 before the first")
    phases: int = Field(0, description="optimisation phases of this run; 0 until known")
    step: int = Field(0, description="optimisation steps done (all phases)")
    steps: int = Field(0, description="optimisation steps of this run (all phases); 0 until known")
    restarts: int = Field(0, description="random restarts of this run")
    fraction: float = Field(0.0, ge=0.0, le=1.0, description="how much of the whole job is done: step / steps, "
                            "and for several alignments (an assembly's objects, copies) each one a 1/count share")
    elapsed_s: float = Field(0.0, description="seconds since the worker started the job")
    eta_s: float | None = Field(None, description="estimated seconds left; null when unknown")
    objective: float | None = Field(
        None, description="objective of the answer so far (the restart the run would answer with now; in the "
        "search, the best candidate) at the last scored step (lower is better; comparable within a phase, whose "
        "weights differ); null before the first score")
    message: str = Field("", description="human-readable status line")
    # What a person reads instead of the objective: its scale changes with each phase's weights.
    relation: str | None = Field(None, description="the prompt's relation where it judges poses (on, in, under, "
                                 "...); null when the prompt has none the engine knows")
    relation_holds: int | None = Field(None, description="where that relation holds: of the candidates scored so "
                                       "far (search) or of the restarts (refinement); null without a relation")
    relation_checked: int | None = Field(None, description="out of this many (relation_holds' denominator)")
    guide_match: float | None = Field(None, description="the answer's match to the prompt's guide: mean "
                                      "cosine between its views and the goal (higher is better); null without a "
                                      "guide, or with one that does not tell the candidates apart")
    contact_gap: float | None = Field(None, description="the answer's gap to the target in source "
                                      "diagonals, within the target's sample spacing (0: touching); null during "
                                      "the search")


class JobError(BaseModel):
    """Why a job or a request failed; ``code`` is stable API, ``message`` is for humans."""

    code: str = Field(description="stable machine-readable code")
    message: str = Field(description="what went wrong, for humans")
    field: str | None = Field(None, description="the request field at fault, when there is one")


class AssemblyAlso(BaseModel):
    """A relation said of a stage's object besides its own (``ctp_core.assembly.plan.Also``): judged with the stage
    and on the final scene."""

    prompt: str
    on: list[str]
    relation: str = ""


class AssemblyStep(BaseModel):
    """One stage of an assembly job as stored: its source (blob ``source-<i>``), guide, name, relation and config.

    The plan's step as the client wrote it is ``ctp_core.assembly.plan.PlanStep`` (file names, options); this is that
    step once checked (the uploads stored as blobs, the options merged into a config), and the worker turns
    it into the engine's ``ctp_core.assembly.assemble.Step`` (meshes loaded, the reference picture decoded)."""

    name: str
    file: str = Field(description="the source's file name (its extension gives the format)")
    prompt: str | None = None
    has_image: bool = Field(False, description="guided by the reference picture in blob image-<i>")
    on: str | list[str] | None = Field(None, description="the placed object(s) it relates to (two: \"between\"); "
                                       "None: the last placed one, or the two a between prompt names")
    also: list[AssemblyAlso] = Field(default_factory=list, description="relations said of it besides its own")
    config: AlignConfig = Field(description="this stage's config (the assembly's options, then the step's), "
                                "validated at submit")


class JobRecord(BaseModel):
    """The stored job. ``owner`` is a digest of the API key, never the key.

    An assembly (``kind`` "assemble") has its base as the target and one ``steps`` entry per stage; an
    alignment chained on an earlier job (``target_job``) has that job's result scene as its target.
    """

    id: str
    owner: str
    status: Status = "queued"
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    progress: Progress = Progress(message="waiting for a worker")
    error: JobError | None = None
    cancel_requested: bool = False
    worker: str | None = None
    prompt: str | None = None
    description: str | None = Field(None, description="an assembly: the scene in one sentence, as the job is "
                                    "labelled (POST /scenes's prompt, POST /assemble's description)")
    has_image: bool = False
    target_name: str = "target"
    source_name: str = "source"
    target_file: str = "target.glb"
    source_file: str = "source.glb"
    config: AlignConfig = Field(description="validated at submit; the worker applies its device, runtime and "
                                "threads when it takes the job")
    kind: Literal["align", "assemble"] = "align"
    target_job: str | None = Field(None, description="the job whose result scene is the target (POST /align)")
    on: str | list[str] | None = Field(None, description="with target_job: the object(s) of its scene the source "
                                       "relates to (two: \"between\")")
    steps: list[AssemblyStep] = Field(default_factory=list, description="an assembly's stages")
    count: int = Field(1, description="copies of the source an alignment places (ctp_core.assembly.copies)")
    arrangement: str | None = Field(None, description="how several copies stand together; None for one")
    alternatives: list[Alternative] = Field(default_factory=list, description="the best distinct placements, the "
                                            "answer first, once the job succeeded")
    webhook: Webhook | None = Field(None, description="where events of this job are delivered, and how that went")
    webhook_progress_at: float | None = Field(None, description="when its last progress event was queued (Unix "
                                              "seconds): the throttle")
    queue: str = Field(DEFAULT_QUEUE, description="the named queue it was sent to")
    attempts: int = Field(0, description="runs of it that workers started and did not hand back; a job whose worker "
                          "was lost (missed its lease) is queued again once, then fails worker_lost")
    downloads: Literal["stream", "redirect"] = Field("stream", description="how its result downloads answer, "
                                                     "as the API that accepted it was set (Links.downloads)")
    adjusted: SavedAdjustment | None = Field(None, description="a succeeded alignment's saved adjustment, the latest")
    guide: str | None = Field(None, description="the guide its worker chose (a model spec or none) when it took it")
    guide_why: str | None = Field(None, description="why that guide (ctp_core.guide.selection)")

    @property
    def stage_count(self) -> int:
        return max(1, len(self.steps))

    def inputs(self) -> list[str]:
        """The names of this job's upload blobs (dropped once it ends)."""
        if self.kind == "assemble":
            return ["target", *(f"{role}-{i}" for i in range(len(self.steps)) for role in ("source", "image"))]
        return list(INPUTS)


def now() -> datetime:
    return datetime.now(UTC)


def new_id() -> str:
    return uuid.uuid4().hex


class _StopFlags(BaseModel):
    """The fields of a stored record that ``Jobs.should_stop`` reads (the others are skipped)."""

    status: Status
    cancel_requested: bool = False
    worker: str | None = None


def parse_record(raw: bytes | str | None) -> JobRecord | None:
    """A stored record, as read from its key or its events channel (None: unknown or expired)."""
    return None if raw is None else JobRecord.model_validate_json(raw)


class Jobs:
    """Job records, the rq queues and the job leases of one deployment (one key prefix); its workers' presence is
    ``workers``."""

    def __init__(self, redis: Redis, storage: Storage, *, prefix: str, ttl_s: int, job_timeout_s: int,
                 lease_s: int, worker_grace_s: float = 0.0, default_queue: str = DEFAULT_QUEUE):
        self.redis, self.storage, self.prefix = redis, storage, prefix
        self.ttl_s, self.job_timeout_s, self.lease_s = ttl_s, job_timeout_s, lease_s
        self.outbox = Outbox(redis, prefix, ttl_s)
        self.default_queue = default_queue
        self.workers = Workers(redis, prefix=prefix, lease_s=lease_s, worker_grace_s=worker_grace_s,
                               default_queue=default_queue)
        self._renew_lease = redis.register_script(_RENEW_LEASE)

    @classmethod
    def from_settings(cls, settings: Settings, client: Redis | None = None) -> Jobs:
        """The job store of a deployment, as the API and every worker reach it (``settings.redis_url``; a worker
        passes its own ``client``, one that waits out an outage)."""
        client = client or Redis.from_url(settings.redis_url, health_check_interval=30)
        return cls(client, open_storage(client, settings), prefix=settings.key_prefix, ttl_s=settings.job_ttl_s,
                   job_timeout_s=settings.job_timeout_s, lease_s=settings.lease_s,
                   worker_grace_s=settings.worker_grace_s, default_queue=settings.default_queue)

    def rq_queue(self, name: str | None = None) -> Queue:
        """The rq queue of a named queue (default: the deployment's), namespaced by the key prefix so that
        deployments sharing a Redis never take each other's jobs."""
        return Queue(f"{self.prefix}:{name or self.default_queue}", connection=self.redis, serializer=JSONSerializer)

    # -- keys ---------------------------------------------------------------------------------------
    def record_key(self, job_id: str) -> str:
        return f"{self.prefix}:job:{job_id}"

    def _lease_key(self, job_id: str) -> str:
        return f"{self.prefix}:lease:{job_id}"

    def _active_key(self, owner: str) -> str:
        return f"{self.prefix}:active:{owner}"

    def _owned_key(self, owner: str) -> str:
        return f"{self.prefix}:owned:{owner}"

    def channel(self, job_id: str) -> str:
        return f"{self.prefix}:events:{job_id}"

    def idempotency_key(self, owner: str, key: str) -> str:
        """Where a submit's ``Idempotency-Key`` is remembered: per owner, the client's key hashed (any bytes)."""
        return f"{self.prefix}:idem:{owner}:{hashlib.sha256(key.encode()).hexdigest()[:32]}"

    @property
    def _running_key(self) -> str:
        return f"{self.prefix}:running"

    @property
    def queued_key(self) -> str:
        """The index of queued jobs: job id -> the id of the rq job that waits for it (``service.reconcile``)."""
        return f"{self.prefix}:queued"

    # -- reading ------------------------------------------------------------------------------------
    def get(self, job_id: str) -> JobRecord | None:
        return parse_record(self.redis.get(self.record_key(job_id)))

    async def get_async(self, aredis: AsyncRedis, job_id: str) -> JobRecord | None:
        """``get`` on the event loop's client: the API's hot path (clients poll their jobs) stays off the
        threadpool, where uploads are checked."""
        return parse_record(await aredis.get(self.record_key(job_id)))

    async def wait_async(self, aredis: AsyncRedis, job_id: str, timeout_s: float) -> JobRecord | None:
        """The record once the job ended, or as it is after ``timeout_s`` (``Prefer: wait``): follows the job's
        events channel, subscribed before the first read so that no change between the two is missed."""
        deadline = asyncio.get_running_loop().time() + timeout_s
        pubsub = aredis.pubsub()
        await pubsub.subscribe(self.channel(job_id))
        try:
            record = await self.get_async(aredis, job_id)
            while record is not None and record.status not in TERMINAL:
                left = deadline - asyncio.get_running_loop().time()
                if left <= 0:
                    break
                message = await pubsub.get_message(ignore_subscribe_messages=True, timeout=min(left, 1.0))
                record = parse_record(message["data"]) if message else await self.get_async(aredis, job_id)
            return record
        finally:
            await pubsub.unsubscribe()
            await pubsub.aclose()

    def owned(self, owner: str, offset: int, limit: int) -> tuple[list[JobRecord], int]:
        """A page of the owner's jobs, newest first, and how many it has; expired ones are forgotten here."""
        key = self._owned_key(owner)
        self.redis.zremrangebyscore(key, "-inf", now().timestamp() - self.ttl_s)
        ids = [raw.decode() for raw in self.redis.zrevrange(key, offset, offset + limit - 1)]
        raws = self.redis.mget([self.record_key(i) for i in ids]) if ids else []
        gone = [job_id for job_id, raw in zip(ids, raws, strict=True) if raw is None]
        if gone:
            self.redis.zrem(key, *gone)
        return [JobRecord.model_validate_json(raw) for raw in raws if raw is not None], self.redis.zcard(key)

    def should_stop(self, job_id: str, worker: str | None = None) -> bool:
        """What a running job polls between steps: cancel requested, or no longer running (reaped), or no longer
        ``worker``'s (reaped, queued again and taken by another). Every optimiser step asks, so only the fields it
        needs are parsed from the record."""
        raw = self.redis.get(self.record_key(job_id))
        flags = None if raw is None else _StopFlags.model_validate_json(raw)
        return (flags is None or flags.cancel_requested or flags.status != "running"
                or (worker is not None and flags.worker != worker))

    # -- writing ------------------------------------------------------------------------------------
    def submit(self, record: JobRecord, blobs: dict[str, bytes], max_active: int,
               claim: tuple[str, str] | None = None) -> JobRecord:
        """Store the inputs, then admit the record under the per-key limit and put it on its queue, in one
        transaction (``_admit``); raises TooManyJobs over the limit (``retry_after_s``: when a slot is likely free).

        The inputs go first, so that no worker ever sees a job without them; the record, the key's slot and the rq
        job are then written together, so no crash leaves a record without its place in the queue or a slot without
        its record, and concurrent submits (any number of API processes) never admit more than the limit.
        ``claim``: the request's ``Idempotency-Key`` claim (key, value), kept as long as the job in that same
        transaction and checked to be still this request's (``ClaimLost`` otherwise). A submit over the limit is
        refused before its inputs are stored, and deletes them when another submit took the last slot meanwhile; one
        whose transaction's outcome is unknown (Redis went away under it) keeps them: they may be the job's, and they
        expire with it. The job's time limit is the configured one per stage (an assembly of n objects gets n times
        it)."""
        if self._taken(self.redis, record.owner) >= max_active:  # the common refusal, before any upload is stored
            raise self._full(record.owner, max_active)
        try:
            for name, data in blobs.items():
                self.storage.put(record.id, name, data)
            faults.point("submit.stored")
            admitted = self._admit(record, max_active, claim)
        except (ClaimLost, StorageUnavailable):
            self.storage.delete(record.id, list(blobs))
            raise
        if not admitted:  # another submit took the last slot meanwhile
            self.storage.delete(record.id, list(blobs))
            raise self._full(record.owner, max_active)
        log.info("job queued", extra={"job_id": record.id, "owner": record.owner, "queue": record.queue})
        faults.point("submit.queued")
        return record

    def _admit(self, record: JobRecord, max_active: int, claim: tuple[str, str] | None) -> bool:
        """The admission (False: the key has its limit of live jobs) and, with it, the record, the slot, the owner's
        index and the rq job, under WATCH of the key's slots: any change to them (another admission, a job ending)
        makes this one count again. A slot whose record ended or expired is forgotten here (released already in the
        transaction that ended it; kept here so that no path can leak a slot)."""
        active, owned = self._active_key(record.owner), self._owned_key(record.owner)
        with self.redis.pipeline() as pipe:
            while True:
                try:
                    pipe.watch(active, *([claim[0]] if claim else []))
                    if claim is not None and pipe.get(claim[0]) != claim[1].encode():
                        raise ClaimLost("the Idempotency-Key's claim lapsed and another request holds it")
                    ended: list[str] = []
                    if self._taken(pipe, record.owner, ended) >= max_active:
                        pipe.unwatch()
                        return False
                    pipe.multi()
                    if ended:
                        pipe.srem(active, *ended)
                    pipe.sadd(active, record.id)
                    pipe.expire(active, self.ttl_s)
                    pipe.set(self.record_key(record.id), record.model_dump_json(), ex=self.ttl_s)
                    pipe.zadd(owned, {record.id: record.created_at.timestamp()})
                    pipe.expire(owned, self.ttl_s)
                    if claim is not None:
                        pipe.expire(claim[0], self.ttl_s)
                    self._enqueue(record, record.id, pipe)
                    pipe.execute()
                    return True
                except WatchError:
                    continue

    def _taken(self, client: Any, owner: str, ended: list[str] | None = None) -> int:
        """How many of ``owner``'s slots hold a live job (read on ``client``: a watching pipeline, or Redis);
        ``ended`` gets the slots whose job ended or expired."""
        ids = [raw.decode() for raw in client.smembers(self._active_key(owner))]
        raws = client.mget([self.record_key(i) for i in ids]) if ids else []
        gone = [i for i, raw in zip(ids, raws, strict=True)
                if raw is None or _StopFlags.model_validate_json(raw).status in TERMINAL]
        if ended is not None:
            ended.extend(gone)
        return len(ids) - len(gone)

    def _enqueue(self, record: JobRecord, rq_id: str, pipe: Any) -> None:
        """Put the job on its rq queue as rq job ``rq_id`` in ``pipe``'s transaction, the one that writes its record
        ``queued`` (a job queued again gets a new one: the rq job of its earlier run may still be finalised by the
        worker that ran it), and note it in the index of queued jobs (``service.reconcile``)."""
        self.rq_queue(record.queue).enqueue(TASK, record.id, job_id=rq_id,
                                            job_timeout=self.job_timeout_s * record.stage_count, result_ttl=0,
                                            failure_ttl=self.ttl_s, description=f"{record.kind} {record.id}",
                                            pipeline=pipe)
        pipe.hset(self.queued_key, record.id, rq_id)

    def _full(self, owner: str, max_active: int) -> TooManyJobs:
        return TooManyJobs(f"this key already has {max_active} queued or running jobs; wait for one to end",
                           retry_after_s=self.retry_after(owner))

    def retry_after(self, owner: str) -> int:
        """Seconds until one of ``owner``'s jobs is likely to end and free a slot: the soonest estimate of its
        running jobs (``progress.eta_s``), within ``SLOT_RETRY_S``; the upper bound when none has one yet."""
        ids = [raw.decode() for raw in self.redis.smembers(self._active_key(owner))]
        records = [parse_record(raw) for raw in self.redis.mget([self.record_key(i) for i in ids])] if ids else []
        etas = [r.progress.eta_s for r in records if r is not None and r.status == "running"
                and r.progress.eta_s is not None]
        low, high = SLOT_RETRY_S
        return high if not etas else min(high, max(low, math.ceil(min(etas))))

    def start(self, job_id: str, worker: str) -> JobRecord | None:
        """queued -> running, taking the lease and counting the attempt; None when the job is gone or no longer
        queued."""

        def change(r: JobRecord) -> JobRecord | None:
            if r.status != "queued":
                return None
            return r.model_copy(update={"status": "running", "started_at": now(), "worker": worker,
                                        "attempts": r.attempts + 1,
                                        "progress": Progress(stage=Stage(name="loading"), kind="loading",
                                                                message="loading meshes")})

        def also(pipe, _r: JobRecord) -> None:
            pipe.set(self._lease_key(job_id), worker, ex=self.lease_s)
            pipe.sadd(self._running_key, job_id)
            pipe.hdel(self.queued_key, job_id)

        record = self._update(job_id, change, also)
        return record if record is not None and record.status == "running" and record.worker == worker else None

    def set_guide(self, job_id: str, guide: str, why: str) -> JobRecord | None:
        """The guide the worker chose for its running job (``ctp_core.guide.selection``), and why."""
        return self._update(job_id, lambda r: r.model_copy(update={"guide": guide, "guide_why": why})
                            if r.status == "running" else None)

    def set_progress(self, job_id: str, progress: Progress, worker: str | None = None) -> JobRecord | None:
        """A running job's progress; from ``worker`` only while the job is its own."""
        return self._update(job_id, lambda r: r.model_copy(update={"progress": progress})
                            if r.status == "running" and worker in (None, r.worker) else None)

    def finish(self, job_id: str, status: Status, error: JobError | None = None,
               alternatives: list[Alternative] | None = None, worker: str | None = None) -> JobRecord | None:
        """running -> a terminal status; frees the key's slot and drops the inputs; a succeeded job keeps its
        ``alternatives``. From ``worker``: only while the job is its own."""
        assert status in TERMINAL

        def change(r: JobRecord) -> JobRecord | None:
            if r.status != "running" or worker not in (None, r.worker):
                return None
            progress = r.progress
            if status == "succeeded":
                progress = progress.model_copy(update={
                    "stage": progress.stage.model_copy(update={"name": "done"}), "kind": "done", "fraction": 1.0,
                    "eta_s": 0.0, "message": "done"})
            else:  # not the last step's "loading model ..." of a job that ended there
                message = f"failed: {error.code}" if status == "failed" and error else status
                progress = progress.model_copy(update={"eta_s": None, "message": message})
            return r.model_copy(update={"status": status, "finished_at": now(), "error": error,
                                        "progress": progress, "alternatives": alternatives or []})

        record = self._update(job_id, change, self._release)
        if record is not None and record.status == status:
            self.storage.delete(job_id, record.inputs())
            log.info("job %s", status, extra={"job_id": job_id, "status": status,
                                              "code": error.code if error else None})
        return record

    def hand_back(self, job_id: str, worker: str) -> JobRecord | None:
        """A stopping ``worker`` gives its running job back: queued again, the attempt not counted. None when the
        job is no longer its own (reaped, canceled); then nothing changes."""
        return self._requeue(job_id, lambda r: r.worker == worker and not r.cancel_requested, counted=False,
                             message="handed back by its worker, which was stopping; waiting for a worker")

    def _requeue(self, job_id: str, when: Callable[[JobRecord], bool], *, counted: bool,
                 message: str) -> JobRecord | None:
        """running -> queued (when ``when`` holds), its lease and running slot dropped, put on its rq queue again;
        ``counted``: the run stays counted in ``attempts``. Returns the queued record, or None."""

        applied = False  # the last ``change`` decides: compare-and-set calls it again after a conflict

        def change(r: JobRecord) -> JobRecord | None:
            nonlocal applied
            applied = r.status == "running" and when(r)
            if not applied:
                return None
            return r.model_copy(update={"status": "queued", "started_at": None, "worker": None,
                                        "attempts": r.attempts if counted else r.attempts - 1,
                                        "progress": Progress(message=message)})

        def also(pipe, r: JobRecord) -> None:  # in the record's transaction: never "queued" without its rq job
            pipe.delete(self._lease_key(job_id))
            pipe.srem(self._running_key, job_id)
            if applied:
                self._enqueue(r, new_id(), pipe)

        record = self._update(job_id, change, also)
        if record is None or not applied:
            return None
        log.warning("job queued again", extra={"job_id": job_id, "status": "queued"})
        return record

    def enqueue_again(self, job_id: str) -> JobRecord | None:
        """A queued job whose rq job no longer waits in its queue (``service.reconcile``): put on its queue again as
        a new rq job, in the transaction that rewrites its record; None when it is no longer queued. An rq job too
        many is harmless: the worker that takes it finds the job no longer queued and skips it (``start``)."""

        def change(r: JobRecord) -> JobRecord | None:
            if r.status != "queued":
                return None
            return r.model_copy(update={"progress": r.progress.model_copy(update={
                "message": "its place in the queue was lost (a worker stopped between taking it and starting it); "
                "queued again"})})

        record = self._update(job_id, change, lambda pipe, r: self._enqueue(r, new_id(), pipe))
        if record is None or record.status != "queued":
            return None
        log.warning("job put on its queue again", extra={"job_id": job_id, "status": "queued"})
        return record

    def mark_adjusted(self, job_id: str, adjusted: SavedAdjustment) -> JobRecord | None:
        """A saved adjustment of a succeeded job (its files are stored already); None for an unknown id."""
        return self._update(job_id, lambda r: r.model_copy(update={"adjusted": adjusted})
                            if r.status == "succeeded" else None)

    def cancel(self, job_id: str) -> JobRecord | None:
        """queued: canceled now and removed from the queue; running: flagged, the worker stops at its
        next step; finished: unchanged. None for an unknown id."""

        def change(r: JobRecord) -> JobRecord | None:
            if r.status == "queued":
                return r.model_copy(update={"status": "canceled", "finished_at": now(), "cancel_requested": True,
                                            "progress": r.progress.model_copy(update={"message": "canceled"}),
                                            "error": JobError(code="canceled", message="canceled before it started")})
            if r.status == "running" and not r.cancel_requested:
                return r.model_copy(update={"cancel_requested": True})
            return None

        def also(pipe, r: JobRecord) -> None:
            if r.status == "canceled":
                self._release(pipe, r)

        record = self._update(job_id, change, also)
        if record is not None and record.status == "canceled" and record.started_at is None:
            # Already dequeued: the worker sees the status and skips it.
            with contextlib.suppress(NoSuchJobError, InvalidJobOperation):
                RqJob.fetch(job_id, connection=self.redis, serializer=JSONSerializer).cancel()
            self.storage.delete(job_id, record.inputs())
            log.info("job canceled while queued", extra={"job_id": job_id})
        return record

    def _release(self, pipe, r: JobRecord) -> None:
        pipe.delete(self._lease_key(r.id))
        pipe.srem(self._running_key, r.id)
        pipe.srem(self._active_key(r.owner), r.id)
        pipe.hdel(self.queued_key, r.id)

    def _update(self, job_id: str, change: Callable[[JobRecord], JobRecord | None],
                also: Callable[[Any, JobRecord], None] | None = None) -> JobRecord | None:
        """Compare-and-set one record; ``change`` returns the new record or None for no change.
        Returns the record as stored afterwards (None when the id is unknown)."""
        key = self.record_key(job_id)

        def write(pipe, old: JobRecord, new: JobRecord) -> JobRecord:
            event = _webhook_event(old, new)
            if event is not None:
                new = new.model_copy(update={
                    "webhook": new.webhook.model_copy(update={"pending": new.webhook.pending + 1}),
                    "webhook_progress_at": time.time() if event == "progress" else new.webhook_progress_at})
            data = new.model_dump_json()
            pipe.multi()
            pipe.set(key, data, keepttl=True)
            pipe.publish(self.channel(job_id), data)
            if event is not None:
                self.outbox.add(pipe, job_id, event, new.webhook.url, data)
            if also is not None:
                also(pipe, new)
            return new

        return compare_and_set(self.redis, key, JobRecord, change, write)

    def delivery_done(self, delivery: Delivery, *, delivered: bool, retry_at: float | None, status: int | None,
                      error: str | None) -> JobRecord | None:
        """Count one delivery attempt of the job's webhook (``service.delivery``) and settle its event in the outbox
        (``Outbox.settle``: due again at ``retry_at``, or gone: delivered or given up, no longer pending), in one
        transaction, so that a deliverer killed after an attempt never leaves the job's count and the outbox apart.
        None when the job's record is gone (its event is settled all the same)."""
        final = retry_at is None
        settled = False

        def change(r: JobRecord) -> JobRecord | None:
            if r.webhook is None:
                return None
            hook = r.webhook
            update = {"attempts": hook.attempts + 1, "last_status": status, "last_error": error}
            if final:
                update["pending"] = max(0, hook.pending - 1)
                if delivered:
                    update["delivered"] = hook.delivered + 1
                else:
                    update["failed"] = hook.failed + 1
            return r.model_copy(update={"webhook": hook.model_copy(update=update)})

        def also(pipe, _r: JobRecord) -> None:
            nonlocal settled
            self.outbox.settle(pipe, delivery, retry_at)
            settled = True

        record = self._update(delivery.job_id, change, also)
        if not settled:
            with self.redis.pipeline() as pipe:
                self.outbox.settle(pipe, delivery, retry_at)
                pipe.execute()
        return record

    # -- liveness -----------------------------------------------------------------------------------
    def heartbeat(self, worker: str, job_id: str | None, models: dict[str, str | None] | None = None,
                  queues: list[str] | None = None, period_s: float | None = None) -> None:
        """A worker is alive (and so is its running job): refresh both leases in one round trip, the worker's
        presence (``Workers.beat``: its offer, its "last seen" record) and its job's lease. A worker beats only
        once its default model is loaded (``worker.main.run_worker``)."""
        with self.redis.pipeline(transaction=False) as pipe:
            self.workers.beat(pipe, worker, job_id, models, queues, period_s)
            if job_id is not None:
                self._renew_lease(keys=[self._lease_key(job_id), self._running_key],
                                  args=[job_id, worker, self.lease_s], client=pipe)
            pipe.execute()

    def unavailable(self, model: str | None, *, queue: str | None = None, what: str = "model",
                    field: str | None = "options.model", live: dict[str, Offer] | None = None,
                    seen: dict[str, SeenWorker] | None = None) -> JobError | None:
        """Why a job on ``queue`` (default: the deployment's) that needs ``model`` (None: a geometry-only job)
        cannot succeed if submitted now, or None when a worker can run it: the one readiness rule of
        ``/readyz`` and the submits.

        The live workers that serve the queue decide. When none does, the workers seen within the grace that
        served it decide (their last offer): a worker that is restarting keeps its queue accepting jobs, which
        wait in it. No worker at all, live or seen: ``no_worker``; workers, but none for this queue:
        ``queue_not_served``. ``live`` / ``seen``: ``workers.live()`` / ``workers.seen()`` when the caller has
        just read them (one read for several models); ``seen`` is read only when no live worker serves the
        queue. ``field``: the request field blamed for a missing model (None: none, as for ``/readyz``)."""
        queue = queue or self.default_queue
        live = self.workers.live() if live is None else live
        judged = serving(live, queue)
        where = "" if queue == self.default_queue else f" of queue {queue!r}"
        who, note = f"live worker{where}", ""
        if not judged:
            seen = self.workers.seen() if seen is None else seen
            if not live and not seen:
                return JobError(code="no_worker", message="no worker is alive: start one with `ctp worker` "
                                "(`ctp serve` without REDIS_URL starts one) or wait until it is back")
            judged = serving(seen, queue)
            if not judged:
                served = served_queues(live, seen)
                return JobError(code="queue_not_served", message=f"no worker serves queue {queue!r} (served now: "
                                f"{', '.join(served)}): ask for one of those, or start workers with "
                                f"CTP_QUEUES={queue}", field=field and "options.queue")
            who, note = f"recently seen worker{where}", " (none is live now)"
        if model is None or any(model in models and models[model] is None for models in judged.values()):
            return None
        reasons = sorted({models[model] for models in judged.values() if models.get(model)})
        why = "; ".join(reasons) if reasons else f"no {who} offers it"
        return JobError(code="model_unavailable", message=f"no {who}{note} can run {what} {model!r}: {why}",
                        field=field)

    def reap(self) -> list[str]:
        """Running jobs whose worker missed its lease: queued again while under ``MAX_ATTEMPTS`` (and not being
        canceled), else failed ``worker_lost``, or canceled when that was asked; returns their ids."""
        reaped = []
        for raw in self.redis.smembers(self._running_key):
            job_id = raw.decode()
            if self.redis.exists(self._lease_key(job_id)):
                continue
            record = self.get(job_id)
            if record is None or record.status in TERMINAL:
                self.redis.srem(self._running_key, job_id)
                continue
            missed = f"the worker running this job missed its lease: no heartbeat for {self.lease_s} s"
            again = self._requeue(job_id, lambda r: r.attempts < MAX_ATTEMPTS and not r.cancel_requested,
                                  counted=True, message=f"{missed}; queued again (attempt {record.attempts + 1} of "
                                  f"{MAX_ATTEMPTS})")
            status: Status = "queued"
            if again is None:
                if (self.get(job_id) or record).cancel_requested:  # what its client asked, not a loss
                    status, error = "canceled", JobError(code="canceled", message=f"{missed}; it was being canceled")
                else:
                    status, error = "failed", JobError(code="worker_lost", message=(
                        f"{missed}; it was not run again (attempt {record.attempts} of {MAX_ATTEMPTS}): "
                        "submit it again"))
                ended = self.finish(job_id, status, error)
                if ended is None or ended.status != status or ended.error != error:
                    continue  # it ended, or expired, meanwhile
            reaped.append(job_id)
            log.warning("job reaped", extra={"job_id": job_id, "worker": record.worker, "status": status})
        return reaped


def _webhook_event(old: JobRecord, new: JobRecord) -> str | None:
    """The webhook event a change of a job is, when its webhook subscribes to it: ``start`` (it began
    running), ``completed`` (it ended: succeeded, failed or canceled), ``progress`` (its progress moved, at
    most one a second, ``PROGRESS_EVERY_S``)."""
    if new.webhook is None or new.status == old.status == "queued":
        return None
    if new.status in TERMINAL:
        event = None if old.status in TERMINAL else "completed"
    elif new.status == "running" and old.status != "running":
        event = "start"
    elif new.progress != old.progress and (new.webhook_progress_at is None
                                           or time.time() - new.webhook_progress_at >= PROGRESS_EVERY_S):
        event = "progress"
    else:
        event = None
    return event if event in new.webhook.events else None


def compare_and_set(redis, key: str, model: type[M], change: Callable[[M], M | None],
                    write: Callable[[Any, M, M], M] | None = None) -> M | None:
    """Read-modify-write one JSON record under WATCH, retried when another writer got there first: ``change``
    returns the new record or None for no change; ``write(pipe, old, new)`` queues the writes after MULTI and
    returns what was stored (default: the record itself, its TTL kept). None when the key is absent."""
    def plain(pipe, old: M, new: M) -> M:
        pipe.multi()
        pipe.set(key, new.model_dump_json(), keepttl=True)
        return new

    with redis.pipeline() as pipe:
        while True:
            try:
                pipe.watch(key)
                raw = pipe.get(key)
                if raw is None:
                    return None
                old = model.model_validate_json(raw)
                new = change(old)
                if new is None:
                    pipe.unwatch()
                    return old
                stored = (write or plain)(pipe, old, new)
                pipe.execute()
                return stored
            except WatchError:
                continue
