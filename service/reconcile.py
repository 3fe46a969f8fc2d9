"""The reconciler: every job whose record says ``queued`` has an rq job waiting for it in its queue.

The API never parts the two: a submit writes the record, the key's slot and the rq job in one transaction, and so
does a job queued again (``Jobs.submit``, ``Jobs._requeue``). What can still part them is a worker that dies between
taking the rq job off its queue and marking the job running (``Jobs.start``): rq's own upkeep then fails its rq job
and never looks at ours, and the record would say ``queued`` until it expired. So every API process runs a pass at
start-up and about once a minute (``service.app``), one pass at a time for the whole deployment (a Redis lock held
for ``EVERY_S``): for each job of the index of queued jobs (``Jobs.queued_key``) whose rq job is not in its queue,
it notes when it first saw that, and once that has lasted ``GRACE_S`` (a worker that took the rq job starts the job
within moments; ``Jobs.start`` then drops it from the index) it puts the job on its queue again
(``Jobs.enqueue_again``). "When first seen" is read from the note's time to live in Redis, so no two machines'
clocks are compared. Entries of jobs no longer queued (started, ended, expired) are dropped.

A running job whose worker is gone is the reaper's: queued again once, then failed ``worker_lost`` (``Jobs.reap``).
"""

from __future__ import annotations

import logging

from service.jobs import Jobs

log = logging.getLogger("ctp.service")

EVERY_S = 60  # one pass a minute for the whole deployment (the lock lives this long)
GRACE_S = 30  # a job out of its queue this long without starting is put back
_NOTE_TTL_S = 3600  # a note's age is this less its time to live
# Drop an index entry only if it still names the rq job read (the job may have been queued again meanwhile).
_FORGET = "if redis.call('HGET', KEYS[1], ARGV[1]) == ARGV[2] then return redis.call('HDEL', KEYS[1], ARGV[1]) end " \
          "return 0"


def reconcile(jobs: Jobs, *, grace_s: float = GRACE_S, force: bool = False) -> list[str]:
    """One pass, unless another API process ran one within ``EVERY_S`` (``force``: regardless, for tests); returns
    the ids of the jobs put on their queue again."""
    redis = jobs.redis
    if not redis.set(f"{jobs.prefix}:reconciler", 1, nx=True, ex=EVERY_S) and not force:
        return []
    again = []
    for raw_id, raw_rq in redis.hgetall(jobs.queued_key).items():
        job_id, rq_id = raw_id.decode(), raw_rq.decode()
        note = f"{jobs.prefix}:stray:{job_id}"
        record = jobs.get(job_id)
        if record is None or record.status != "queued":
            redis.eval(_FORGET, 1, jobs.queued_key, job_id, rq_id)
            redis.delete(note)
            continue
        if redis.lpos(jobs.rq_queue(record.queue).key, rq_id) is not None:  # waiting its turn
            redis.delete(note)
            continue
        if redis.get(note) != raw_rq:  # first seen out of its queue now (or the note was of an earlier rq job)
            redis.set(note, rq_id, ex=_NOTE_TTL_S)
            if grace_s > 0:
                continue
        elif _NOTE_TTL_S - redis.ttl(note) < grace_s:
            continue
        if jobs.enqueue_again(job_id) is not None:
            again.append(job_id)
        redis.delete(note)
    if again:
        log.warning("reconciler: %d queued job(s) had lost their place in the queue and were put back", len(again),
                    extra={"jobs": again})
    return again
