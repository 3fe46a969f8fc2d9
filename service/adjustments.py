"""Adjustments of a succeeded job (``POST /jobs/{id}/adjust``): short jobs of their own.

A person moved the source by hand (the page's handles); an adjustment measures that placement as the search
measures its poses (penetration, contact gap, the relation's verdict), first settles it into contact when asked
("drop", "push": ``ctp_core.adjust``), and with ``save`` stores it as the job's result (``result.glb`` and
``report.json`` replaced, the run's own GLB kept as ``original.glb``), so that downloads and ``target_job``
chaining use it. An assembly's adjustment moves one of its placed objects (``object``) against all the others and
judges every relation of the scene again (``ctp_core.assembly.adjusted``). It needs the engine (torch), so it runs
on a worker of the job's queue; the API only checks and queues it.

An adjustment is a record ``{prefix}:adjust:{id}`` (status, the request, the outcome or the error) that lives as
long as the job's results (``CTP_JOB_TTL_S``) and an rq job on the job's queue that carries only its id; it is
not a job of ``GET /jobs`` and does not count against ``CTP_MAX_ACTIVE_JOBS``. A worker that dies while running
one leaves it ``running``: reading it then finds its worker gone and fails it ``worker_lost``.

    queued -> running -> succeeded | failed
"""

from __future__ import annotations

import logging
import uuid
from datetime import datetime
from typing import Literal

from pydantic import BaseModel, Field

from ctp_core.reading.names import NAME_MAX
from service.jobs import JobError, Jobs, compare_and_set, now
from service.redact import redact_model

log = logging.getLogger("ctp.service")

TASK = "worker.tasks.run_adjustment"  # by name: the API never imports the engine
AdjustStatus = Literal["queued", "running", "succeeded", "failed"]
ENDED = frozenset({"succeeded", "failed"})


class AdjustRequest(BaseModel):
    """The body of ``POST /jobs/{id}/adjust``."""

    transform: list[list[float]] = Field(
        description="the source's 4x4, source file frame -> target file frame, row-major (as the report's "
        "`transform.matrix` and the GLB's source node; an assembly's object: its file frame -> the scene, as the "
        "report's `objects`): a rotation, one scale and a translation; 422 `invalid_transform` otherwise")
    settle: Literal["none", "drop", "push"] = Field(
        "none", description="none: measured where it is; drop: lowered along the target's up (as the job turned "
        "it upright) until it touches the target, or rests on the plane the target stands on; push: moved along "
        "`direction` until it touches, left where it is when nothing is met")
    direction: list[float] | None = Field(
        None, description="push: the direction to move along, target file frame (the page sends its view "
        "direction, eye into the scene); 422 `invalid_direction` when push has none")
    save: bool = Field(False, description="store the outcome as the job's result: result.glb and report.json "
                       "(`adjusted` true) replaced, the run's own GLB kept as original.glb")
    copy_index: int | None = Field(None, ge=1, description="a job of several copies (options.count): which copy, "
                             "1-based as the report's `copies`, the transform is for (422 `invalid_copy` when "
                             "missing or past the count; the others stay where they are); none for one source")
    object: str | None = Field(None, min_length=1, max_length=NAME_MAX, description="an assembly: the placed "
                               "object (its name, as the report's `objects`) the transform is for; the others stay "
                               "where they are, every relation is judged again (422 `invalid_object` when missing, "
                               "unknown or the base, which stays put); none for an alignment")


class AdjustOutcome(BaseModel):
    """Where the source ended and how it sits there (lengths in source diagonals, as the job's progress)."""

    transform: list[list[float]] = Field(description="the source's 4x4 now, source file -> target file, row-major")
    settled: bool | None = Field(description="drop, push: whether it came to rest touching (false: nothing was "
                                 "met, `transform` is the one sent); null for none")
    moved: float = Field(description="how far settling moved it")
    on_floor: bool = Field(description="drop: it rests on the plane the target stands on, not on the target")
    penetration: float = Field(description="penetration into the target over the source's diagonal (the search "
                               "counts a pose past 0.01 as intersecting)")
    contact_gap: float = Field(description="gap to the target, within the target's sample spacing (0: touching)")
    touching: bool = Field(description="the gap is within 0.1, what the answer's selection counts as touching")
    relation: dict | None = Field(None, description="the prompt's relation judged here (name, role, score, holds, "
                                  "stable); null without one")
    whole: dict | None = Field(None, description="an assembly: every relation of the scene judged again with the "
                               "object here (as the report's `whole`); null for an alignment")
    stands_on: dict[str, str] | None = Field(None, description="an assembly: what each object stands on now (an "
                                             "object's name, or floor); null for an alignment")
    saved: bool = Field(description="stored as the job's result")


class Adjustment(BaseModel):
    """An adjustment as clients see it."""

    id: str = Field(description="adjustment id")
    job: str = Field(description="the job it adjusts")
    status: AdjustStatus = Field(description="queued, running, succeeded or failed")
    created_at: datetime = Field(description="when the API accepted it (UTC)")
    finished_at: datetime | None = Field(None, description="when it ended (UTC)")
    request: AdjustRequest
    result: AdjustOutcome | None = Field(None, description="once succeeded")
    error: JobError | None = Field(None, description="why it failed: job_not_ready (the job's results are gone), "
                                   "invalid_transform, invalid_direction, worker_lost, job_timeout, ...")
    link: str = Field(description="this adjustment (GET it until it ends)")


class AdjustmentRecord(BaseModel):
    """The stored adjustment: ``Adjustment`` plus whose it is, its queue and its worker."""

    id: str
    job: str
    owner: str
    queue: str
    status: AdjustStatus = "queued"
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    worker: str | None = None
    request: AdjustRequest
    result: AdjustOutcome | None = None
    error: JobError | None = None

    def out(self) -> Adjustment:
        return Adjustment(id=self.id, job=self.job, status=self.status, created_at=self.created_at,
                          finished_at=self.finished_at, request=self.request, result=self.result,
                          error=self.error and redact_model(self.error),
                          link=f"/jobs/{self.job}/adjust/{self.id}")


class Adjustments:
    """Adjustment records and their rq jobs, beside a deployment's job store (same Redis, prefix, queues)."""

    def __init__(self, jobs: Jobs):
        self.jobs = jobs

    def key(self, adjustment_id: str) -> str:
        return f"{self.jobs.prefix}:adjust:{adjustment_id}"

    def lock(self, job_id: str):
        """Held while a save replaces a job's results: two saves of one job never interleave their files."""
        return self.jobs.redis.lock(f"{self.jobs.prefix}:adjusting:{job_id}", timeout=self.jobs.job_timeout_s,
                                    blocking_timeout=self.jobs.job_timeout_s)

    def submit(self, job_id: str, owner: str, queue: str, request: AdjustRequest) -> AdjustmentRecord:
        """Store the record and queue it on the job's queue, at its front (a person waits for it; alignments
        take minutes), with the job time limit."""
        record = AdjustmentRecord(id=uuid.uuid4().hex, job=job_id, owner=owner, queue=queue, created_at=now(),
                                  request=request)
        key = self.key(record.id)
        self.jobs.redis.set(key, record.model_dump_json(), ex=self.jobs.ttl_s)
        try:
            self.jobs.rq_queue(queue).enqueue(TASK, record.id, job_id=f"adjust-{record.id}",
                                              job_timeout=self.jobs.job_timeout_s, result_ttl=0,
                                              failure_ttl=self.jobs.ttl_s, description=f"adjust {job_id}",
                                              at_front=True)
        except Exception:
            self.jobs.redis.delete(key)
            raise
        log.info("adjustment queued", extra={"job_id": job_id, "adjustment": record.id, "queue": queue})
        return record

    def get(self, adjustment_id: str) -> AdjustmentRecord | None:
        """The record; one left running by a worker that is gone is failed ``worker_lost`` here."""
        raw = self.jobs.redis.get(self.key(adjustment_id))
        record = None if raw is None else AdjustmentRecord.model_validate_json(raw)
        if record is not None and record.status == "running" and not self.jobs.workers.is_live(record.worker or ""):
            record = self.finish(record.id, "failed", error=JobError(
                code="worker_lost", message="the worker running this adjustment stopped; send it again")) or record
        return record

    def start(self, adjustment_id: str, worker: str) -> AdjustmentRecord | None:
        """queued -> running on ``worker``; None when it is gone or not queued."""
        record = self._update(adjustment_id, lambda r: r.model_copy(update={
            "status": "running", "started_at": now(), "worker": worker}) if r.status == "queued" else None)
        return record if record is not None and record.status == "running" and record.worker == worker else None

    def finish(self, adjustment_id: str, status: AdjustStatus, result: AdjustOutcome | None = None,
               error: JobError | None = None) -> AdjustmentRecord | None:
        """running -> succeeded | failed (an ended one is left as it is)."""
        return self._update(adjustment_id, lambda r: None if r.status in ENDED else r.model_copy(update={
            "status": status, "finished_at": now(), "result": result, "error": error}))

    def _update(self, adjustment_id: str, change) -> AdjustmentRecord | None:
        """Compare-and-set one record (a worker finishing it and a reader failing it may race)."""
        return compare_and_set(self.jobs.redis, self.key(adjustment_id), AdjustmentRecord, change)
