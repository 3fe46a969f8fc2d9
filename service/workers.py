"""Which workers a deployment has: alive now, seen within the grace, and what each offers (the worker-presence
registry; ``service.jobs.Jobs.workers``).

Each heartbeat refreshes the worker's own lease ``{prefix}:worker:{name}`` (``FRESH_BEATS``) with
its offer ``{prefix}:offer:{name}`` (the queues it serves, the models it can run), and a "last seen"
record ``{prefix}:seen:{name}`` that outlives the lease by the grace (``worker_grace_s``). A job is judged
by the live workers that serve its queue; while none does but one was seen within the grace (a worker
being restarted: killed, back-off, start-up, model load), by what the last-seen ones offered, and it is
accepted and waits in its queue until a worker is back. A clean exit drops the lease but not the record,
so it does not end the grace early.
"""

from __future__ import annotations

import json

from pydantic import BaseModel, Field
from redis import Redis
from redis.client import Pipeline

from service.settings import DEFAULT_QUEUE

FRESH_BEATS = 3  # a worker counts as live while it beat within this many heartbeat periods (``Workers.beat``)


class Offer(BaseModel):
    """What a worker serves, as its heartbeat publishes it: the named queues it takes jobs from and the models
    it can run (``{spec: None when it can, else why not}``)."""

    queues: list[str] = Field(default_factory=lambda: [DEFAULT_QUEUE])
    models: dict[str, str | None] = Field(default_factory=dict)


class SeenWorker(Offer):
    """A worker seen within the grace (``Workers.seen``): how long ago, and what it offered then."""

    since_s: float


def serving(workers: dict[str, Offer], queue: str) -> dict[str, dict[str, str | None]]:
    """The workers (live or seen) that serve ``queue`` -> the models each can run."""
    return {name: offer.models for name, offer in workers.items() if queue in offer.queues}


def served_queues(*workers: dict[str, Offer]) -> list[str]:
    """Every queue the given workers (live, seen) serve, sorted."""
    return sorted({queue for group in workers for offer in group.values() for queue in offer.queues})


class Workers:
    """The presence keys of one deployment's workers (one key prefix): written by their heartbeats, read by the
    readiness rule (``Jobs.unavailable``: ``/readyz``, the submits) and by the adjustments (``is_live``)."""

    def __init__(self, redis: Redis, *, prefix: str, lease_s: int, worker_grace_s: float, default_queue: str):
        self.redis, self.prefix, self.lease_s = redis, prefix, lease_s
        self.worker_grace_s = worker_grace_s  # how long a heartbeat's "last seen" record lives; 0: none written
        self.default_queue = default_queue

    def _worker_key(self, worker: str) -> str:
        return f"{self.prefix}:worker:{worker}"

    def _offer_key(self, worker: str) -> str:
        return f"{self.prefix}:offer:{worker}"

    def _seen_key(self, worker: str) -> str:
        return f"{self.prefix}:seen:{worker}"

    @property
    def _live_set(self) -> str:
        return f"{self.prefix}:workers"

    @property
    def _seen_set(self) -> str:
        return f"{self.prefix}:seen"

    def beat(self, pipe: Pipeline, worker: str, job_id: str | None, models: dict[str, str | None] | None,
             queues: list[str] | None, period_s: float | None) -> None:
        """Queue on ``pipe`` a heartbeat's presence writes (``Jobs.heartbeat`` adds the job's lease and sends them).

        The worker's offer, the ``queues`` it serves (default: the default queue) and the ``models`` it can run
        (``{spec: None when it can, else why not}``), lives as long as the worker's lease. With a grace, the
        worker's "last seen" record (its offer) is refreshed too and lives ``worker_grace_s``.

        ``period_s``: the worker's heartbeat period; its own lease then lapses after ``FRESH_BEATS`` missed beats
        (at least 2 s) instead of the whole ``lease_s``, so that a worker killed a moment ago no longer counts as
        live (``/readyz``, the submits) while its job's lease still runs."""
        offer = Offer(queues=queues or [self.default_queue], models=models or {})
        fresh_ms = int(1000 * (self.lease_s if period_s is None else min(self.lease_s, max(FRESH_BEATS * period_s,
                                                                                            2.0))))
        pipe.set(self._worker_key(worker), job_id or "", px=fresh_ms)
        pipe.sadd(self._live_set, worker)
        pipe.set(self._offer_key(worker), offer.model_dump_json(), ex=self.lease_s)
        grace_ms = int(self.worker_grace_s * 1000)
        if grace_ms > 0:
            # The grace travels in the record: "seen s ago" is the grace less the key's time to live, which
            # Redis keeps, so no two machines' clocks are compared.
            pipe.set(self._seen_key(worker), json.dumps({**offer.model_dump(), "grace_s": self.worker_grace_s}),
                     px=grace_ms)
            pipe.sadd(self._seen_set, worker)
            pipe.pexpire(self._seen_set, grace_ms)

    def is_live(self, worker: str) -> bool:
        """Whether ``worker``'s lease is current (it is alive)."""
        return bool(self.redis.exists(self._worker_key(worker)))

    def gone(self, worker: str) -> None:
        """A worker's clean exit: it is no longer live. Its "last seen" record stays for the rest of the grace
        (a supervised or orchestrated worker that exits is usually started again)."""
        self.redis.delete(self._worker_key(worker), self._offer_key(worker))
        self.redis.srem(self._live_set, worker)

    def live(self) -> dict[str, Offer]:
        """Workers whose lease is current -> the offer each published; forgets the others (O(workers), not a
        key-space scan)."""
        names = [raw.decode() for raw in self.redis.smembers(self._live_set)]
        with self.redis.pipeline(transaction=False) as pipe:
            for name in names:
                pipe.exists(self._worker_key(name))
                pipe.get(self._offer_key(name))
            replies = pipe.execute()
        live = {name: Offer.model_validate_json(raw) if raw else Offer()
                for name, ok, raw in zip(names, replies[0::2], replies[1::2], strict=True) if ok}
        dead = [name for name in names if name not in live]
        if dead:
            self.redis.srem(self._live_set, *dead)
        return live

    def seen(self) -> dict[str, SeenWorker]:
        """Workers seen within the grace (live ones included) -> when and with which models; forgets the
        others. Empty without a grace."""
        names = [raw.decode() for raw in self.redis.smembers(self._seen_set)]
        if not names:
            return {}
        with self.redis.pipeline(transaction=False) as pipe:
            for name in names:
                pipe.get(self._seen_key(name))
                pipe.pttl(self._seen_key(name))
            replies = pipe.execute()
        seen = {}
        for name, raw, ttl_ms in zip(names, replies[0::2], replies[1::2], strict=True):
            if raw is None:
                continue
            record = json.loads(raw)
            left_s = ttl_ms / 1000 if ttl_ms >= 0 else 0.0
            seen[name] = SeenWorker(since_s=round(max(0.0, float(record.pop("grace_s")) - left_s), 1), **record)
        gone = [name for name in names if name not in seen]
        if gone:
            self.redis.srem(self._seen_set, *gone)
        return seen
