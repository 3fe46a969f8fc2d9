"""The job life cycle, liveness and storage against a real Redis, without HTTP or workers: the races
the service relies on (cancel vs pickup, reaper vs a live worker) and the TTL bookkeeping."""

from __future__ import annotations

import os
import threading
import time
import uuid
from concurrent.futures import ThreadPoolExecutor
from types import SimpleNamespace

import pytest
import redis

from ctp_core.config import AlignConfig
from service.jobs import ClaimLost, JobError, JobRecord, Jobs, Progress, TooManyJobs, new_id, now
from service.reconcile import reconcile
from service.settings import Settings
from service.storage import DirStorage, RedisStorage


@pytest.fixture
def jobs(private_redis):
    client = redis.Redis.from_url(private_redis.url)
    prefix = f"unit-{uuid.uuid4().hex[:8]}"
    yield Jobs(client, RedisStorage(client, prefix, 600), prefix=prefix, ttl_s=600, job_timeout_s=60, lease_s=1)
    client.close()


def queued(jobs: Jobs, owner: str = "me", max_active: int = 10) -> JobRecord:
    record = JobRecord(id=new_id(), owner=owner, created_at=now(), prompt="p", config=AlignConfig())
    return jobs.submit(record, {"target": b"t", "source": b"s"}, max_active)


def test_submit_stores_inputs_record_and_rq_job(jobs):
    record = queued(jobs)
    assert jobs.get(record.id).status == "queued"
    assert jobs.storage.get(record.id, "target") == b"t"
    assert jobs.rq_queue().get_job_ids() == [record.id]
    assert 0 < jobs.redis.ttl(f"{jobs.prefix}:job:{record.id}") <= 600


def test_cancel_wins_over_a_later_pickup(jobs):
    record = queued(jobs)
    assert jobs.cancel(record.id).status == "canceled"
    assert jobs.start(record.id, "w1") is None  # the worker skips it
    assert jobs.rq_queue().get_job_ids() == []
    assert jobs.storage.get(record.id, "target") is None  # inputs dropped


def test_a_failed_job_says_so_in_its_progress(jobs):
    record = queued(jobs)
    jobs.start(record.id, "w1")
    jobs.set_progress(record.id, Progress(kind="model", message="loading model hf:x", eta_s=30.0))
    failed = jobs.finish(record.id, "failed", JobError(code="model_unavailable", message="no weights"))
    assert (failed.progress.message, failed.progress.eta_s) == ("failed: model_unavailable", None)


def test_only_one_worker_can_start_a_job(jobs):
    record = queued(jobs)
    assert jobs.start(record.id, "w1").worker == "w1"
    assert jobs.start(record.id, "w2") is None


def test_running_cancel_is_a_flag_the_worker_polls(jobs):
    record = queued(jobs)
    jobs.start(record.id, "w1")
    assert not jobs.should_stop(record.id)
    flagged = jobs.cancel(record.id)
    assert flagged.status == "running" and flagged.cancel_requested
    assert jobs.should_stop(record.id)
    done = jobs.finish(record.id, "canceled", JobError(code="canceled", message="x"))
    assert done.status == "canceled" and done.finished_at is not None
    assert jobs.finish(record.id, "succeeded").status == "canceled"  # terminal states are final


def test_progress_is_published_to_the_job_channel(jobs):
    record = queued(jobs)
    pubsub = jobs.redis.pubsub(ignore_subscribe_messages=True)
    pubsub.subscribe(jobs.channel(record.id))
    jobs.start(record.id, "w1")
    jobs.set_progress(record.id, Progress(kind="step", step=3, steps=10, fraction=0.3, message="m"))
    seen = []
    deadline = time.monotonic() + 5
    while len(seen) < 2 and time.monotonic() < deadline:
        message = pubsub.get_message(timeout=0.5)
        if message:
            seen.append(JobRecord.model_validate_json(message["data"]))
    pubsub.close()
    assert [r.status for r in seen] == ["running", "running"]
    assert seen[-1].progress.step == 3


def lapse(jobs: Jobs, job_id: str, live: str | None = None, live_job: str | None = None) -> None:
    """Until the job's lease (1 s) lapsed, ``live`` beating meanwhile."""
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline and jobs.redis.exists(f"{jobs.prefix}:lease:{job_id}"):
        if live:
            jobs.heartbeat(live, live_job)
        time.sleep(0.2)
    if live:
        jobs.heartbeat(live, live_job)


def test_reaper_queues_a_lost_job_again_once_then_fails_it_and_spares_live_ones(jobs):
    dead, live = queued(jobs), queued(jobs)
    jobs.start(dead.id, "gone")
    jobs.start(live.id, "alive")
    lapse(jobs, dead.id, "alive", live.id)
    assert jobs.reap() == [dead.id]
    again = jobs.get(dead.id)
    assert (again.status, again.attempts, again.worker, again.error) == ("queued", 1, None, None)
    assert again.progress.message.startswith("the worker running this job missed its lease")  # no host named
    assert "attempt 2 of 2" in again.progress.message
    assert len(jobs.rq_queue().get_job_ids()) == 3  # on its queue again, as a new rq job
    assert jobs.get(live.id).status == "running"
    assert jobs.should_stop(dead.id, "gone")  # a worker that was only frozen stops once it wakes
    jobs.heartbeat("gone", dead.id)  # ... and cannot revive the lease
    assert not jobs.redis.exists(f"{jobs.prefix}:lease:{dead.id}")
    assert jobs.reap() == []

    assert jobs.start(dead.id, "second").attempts == 2
    assert jobs.should_stop(dead.id, "gone") and not jobs.should_stop(dead.id, "second")
    assert jobs.finish(dead.id, "succeeded", worker="gone").status == "running"  # the frozen one's late writes
    assert jobs.set_progress(dead.id, Progress(message="late"), "gone").progress.message != "late"
    lapse(jobs, dead.id, "alive", live.id)
    assert jobs.reap() == [dead.id]
    failed = jobs.get(dead.id)
    assert (failed.status, failed.error.code, failed.attempts) == ("failed", "worker_lost", 2)
    assert failed.error.message == ("the worker running this job missed its lease: no heartbeat for 1 s; it "
                                    "was not run again (attempt 2 of 2): submit it again")
    assert jobs.storage.get(dead.id, "target") is None  # inputs dropped once it ended


def test_a_lease_that_lapsed_in_a_redis_outage_is_renewed_by_the_next_heartbeat(jobs):
    record = queued(jobs)
    jobs.start(record.id, "w1")
    jobs.redis.delete(f"{jobs.prefix}:lease:{record.id}")  # as when Redis was away for longer than the lease
    jobs.heartbeat("w1", record.id)
    assert jobs.redis.exists(f"{jobs.prefix}:lease:{record.id}") and jobs.reap() == []
    jobs.finish(record.id, "succeeded")
    jobs.heartbeat("w1", record.id)  # a beat that raced the job's end does not bring its lease back
    assert not jobs.redis.exists(f"{jobs.prefix}:lease:{record.id}")


def test_a_lost_job_being_canceled_is_not_run_again(jobs):
    """It ends as its client asked, canceled, not failed by the loss of its worker."""
    record = queued(jobs)
    jobs.start(record.id, "gone")
    jobs.cancel(record.id)
    lapse(jobs, record.id)
    assert jobs.reap() == [record.id]
    ended = jobs.get(record.id)
    assert (ended.status, ended.error.code) == ("canceled", "canceled")
    assert ended.error.message.endswith("; it was being canceled")


def test_a_submit_writes_record_slot_and_rq_job_together_or_not_at_all(jobs, monkeypatch):
    """One transaction: a failure while it is built (here the rq job's) leaves no record, no slot and no rq job."""
    def broken(*_args):
        raise RuntimeError("cut between the record and the queue")

    monkeypatch.setattr(jobs, "_enqueue", broken)
    record = JobRecord(id=new_id(), owner="me", created_at=now(), prompt="p", config=AlignConfig())
    with pytest.raises(RuntimeError):
        jobs.submit(record, {"target": b"t", "source": b"s"}, 10)
    assert jobs.get(record.id) is None and jobs.rq_queue().get_job_ids() == []
    assert not jobs.redis.exists(f"{jobs.prefix}:active:me") and not jobs.redis.exists(jobs.queued_key)


def test_a_submit_keeps_its_idempotency_claim_with_the_job_or_makes_none(jobs):
    """The claim (renewed for seconds at a time while the request checks its job) lives as long as the job from the
    transaction that queues it; a claim another request took over makes no job and keeps no upload."""
    record = JobRecord(id=new_id(), owner="me", created_at=now(), prompt="p", config=AlignConfig())
    jobs.redis.set("claim", "theirs", ex=10)
    with pytest.raises(ClaimLost):
        jobs.submit(record, {"target": b"t", "source": b"s"}, 10, claim=("claim", "mine"))
    assert jobs.get(record.id) is None and jobs.storage.get(record.id, "target") is None
    jobs.redis.set("claim", "mine", ex=10)
    jobs.submit(record, {"target": b"t", "source": b"s"}, 10, claim=("claim", "mine"))
    assert jobs.get(record.id).status == "queued" and 10 < jobs.redis.ttl("claim") <= 600


def test_a_queued_job_whose_rq_job_left_its_queue_is_put_back(jobs):
    """A worker took the rq job off the queue (rq moves it to its intermediate list) and died before starting the
    job: the reconciler notes it, and once that has lasted its grace puts the job on its queue again; an entry of a
    job no longer queued is dropped."""
    record = queued(jobs)
    queue = jobs.rq_queue()
    jobs.redis.lmove(queue.key, queue.intermediate_queue_key)
    assert reconcile(jobs, force=True) == []  # first seen out of its queue: within the grace
    assert reconcile(jobs, force=True, grace_s=0) == [record.id]
    (rq_id,) = queue.get_job_ids()
    assert rq_id != record.id and jobs.redis.hget(jobs.queued_key, record.id).decode() == rq_id
    assert jobs.get(record.id).progress.message.startswith("its place in the queue was lost")
    assert reconcile(jobs, force=True, grace_s=0) == []  # waiting in its queue: left alone
    assert jobs.start(record.id, "w1").attempts == 1 and not jobs.redis.hexists(jobs.queued_key, record.id)
    stale = queued(jobs)
    jobs.redis.delete(jobs.record_key(stale.id))  # expired while queued
    assert reconcile(jobs, force=True, grace_s=0) == [] and not jobs.redis.hexists(jobs.queued_key, stale.id)


def test_one_reconciler_pass_a_minute_for_the_whole_deployment(jobs):
    record = queued(jobs)
    queue = jobs.rq_queue()
    jobs.redis.lmove(queue.key, queue.intermediate_queue_key)
    assert reconcile(jobs, grace_s=0) == [record.id]  # the pass of this minute
    jobs.redis.lmove(queue.key, queue.intermediate_queue_key)
    assert reconcile(jobs, grace_s=0) == []  # another API process's pass, the same minute: none
    assert 50 < jobs.redis.ttl(f"{jobs.prefix}:reconciler") <= 60


def test_a_stopping_worker_hands_its_job_back_uncounted(jobs):
    record = queued(jobs)
    jobs.start(record.id, "w1")
    assert jobs.hand_back(record.id, "w2") is None  # not its job
    back = jobs.hand_back(record.id, "w1")
    assert (back.status, back.attempts, back.worker, back.started_at) == ("queued", 0, None, None)
    assert back.progress.message.startswith("handed back by its worker")
    assert not jobs.redis.exists(f"{jobs.prefix}:lease:{record.id}")
    assert jobs.hand_back(record.id, "w1") is None  # queued already: not put on the queue twice
    assert len(jobs.rq_queue().get_job_ids()) == 2
    assert jobs.start(record.id, "w2").attempts == 1
    jobs.cancel(record.id)
    assert jobs.hand_back(record.id, "w2") is None  # being canceled: it ends canceled instead


def test_live_workers_are_those_with_current_leases_only(jobs):
    jobs.heartbeat("a", None)
    jobs.heartbeat("b", None, {"random:tiny": None})
    live = jobs.workers.live()
    assert {name: offer.models for name, offer in live.items()} == {"a": {}, "b": {"random:tiny": None}}
    assert [offer.queues for offer in live.values()] == [["default"], ["default"]]  # a heartbeat's default
    jobs.workers.gone("a")
    assert list(jobs.workers.live()) == ["b"]
    time.sleep(1.2)  # lease_s = 1
    assert jobs.workers.live() == {}


def test_unavailable_says_no_worker_then_which_model_is_missing(jobs):
    assert jobs.unavailable("random:tiny").code == "no_worker"
    assert jobs.unavailable(None).code == "no_worker"  # even a geometry-only job needs a worker
    jobs.heartbeat("a", None, {"hf:big": "weights for 'big' are not in the cache", "random:tiny": None})
    jobs.heartbeat("b", None, {"hf:big": "weights for 'big' are not in the cache"})
    assert jobs.unavailable("random:tiny") is None and jobs.unavailable(None) is None
    missing = jobs.unavailable("hf:big")
    assert (missing.code, missing.field) == ("model_unavailable", "options.model")
    assert missing.message == "no live worker can run model 'hf:big': weights for 'big' are not in the cache"
    assert "no live worker offers it" in jobs.unavailable("random:ViT-B-32").message
    assert sorted(jobs.workers.live()) == ["a", "b"]
    jobs.workers.gone("a")
    assert jobs.unavailable("random:tiny").code == "model_unavailable"  # the one worker that had it left
    assert not jobs.redis.exists(f"{jobs.prefix}:offer:a")


def test_named_queues_are_judged_by_their_own_workers_and_route_jobs(jobs):
    jobs.heartbeat("g", None, {"hf:big": None, "random:tiny": "no GPU model here"}, ["gpu"])
    jobs.heartbeat("c", None, {"random:tiny": None})  # the default queue
    assert jobs.unavailable("random:tiny") is None and jobs.unavailable("hf:big", queue="gpu") is None
    assert jobs.unavailable("hf:big").code == "model_unavailable"  # the default queue's workers cannot run it
    assert jobs.unavailable("random:tiny", queue="gpu").message == (
        "no live worker of queue 'gpu' can run model 'random:tiny': no GPU model here")
    refused = jobs.unavailable(None, queue="tpu")
    assert (refused.code, refused.field) == ("queue_not_served", "options.queue")
    assert "served now: default, gpu" in refused.message and "CTP_QUEUES=tpu" in refused.message
    record = JobRecord(id=new_id(), owner="me", created_at=now(), prompt="p", config=AlignConfig(), queue="gpu")
    jobs.submit(record, {"target": b"t", "source": b"s"}, 10)
    assert jobs.rq_queue("gpu").name == f"{jobs.prefix}:gpu"  # namespaced: deployments sharing a Redis stay apart
    assert (jobs.rq_queue("gpu").get_job_ids(), jobs.rq_queue().get_job_ids()) == ([record.id], [])


def test_active_job_cap_is_per_owner_and_self_heals(jobs):
    first, _ = queued(jobs, max_active=2), queued(jobs, max_active=2)
    with pytest.raises(TooManyJobs):
        queued(jobs, max_active=2)
    queued(jobs, owner="someone else", max_active=2)
    jobs.redis.delete(f"{jobs.prefix}:job:{first.id}")  # a record that expired without releasing its slot
    queued(jobs, max_active=2)


def test_a_refused_submit_writes_nothing_to_storage(jobs, monkeypatch):
    """Admission comes first: a refused submit costs the storage nothing (an S3 put per input, otherwise)."""
    queued(jobs, max_active=1)
    puts = []
    monkeypatch.setattr(jobs.storage, "put", lambda job_id, name, data: puts.append((job_id, name)))
    refused = JobRecord(id=new_id(), owner="me", created_at=now(), prompt="p", config=AlignConfig())
    with pytest.raises(TooManyJobs):
        jobs.submit(refused, {"target": b"t", "source": b"s"}, 1)
    assert puts == [] and jobs.get(refused.id) is None


def test_owned_lists_an_owners_jobs_newest_first_and_forgets_expired_ones(jobs):
    mine = [queued(jobs) for _ in range(3)]
    queued(jobs, owner="someone else")
    page, total = jobs.owned("me", 0, 2)
    assert ([r.id for r in page], total) == ([mine[2].id, mine[1].id], 3)
    assert [r.id for r in jobs.owned("me", 2, 2)[0]] == [mine[0].id]
    jobs.redis.delete(f"{jobs.prefix}:job:{mine[1].id}")  # its record expired
    page, total = jobs.owned("me", 0, 10)
    assert ([r.id for r in page], total) == ([mine[2].id, mine[0].id], 2)
    assert jobs.owned("nobody", 0, 10) == ([], 0)


def test_dir_storage_round_trip_and_sweep(tmp_path):
    store = DirStorage(tmp_path, ttl_s=60)
    store.put("job1", "result.glb", b"abc")
    assert store.get("job1", "result.glb") == b"abc"
    assert store.get("job1", "missing") is None
    with pytest.raises(ValueError):
        store.put("../x", "a", b"")
    store.put("job2", "report.json", b"{}")
    old = time.time() - 120
    os.utime(tmp_path / "job1", (old, old))
    assert store.sweep() == 1
    assert store.get("job1", "result.glb") is None and store.get("job2", "report.json") == b"{}"
    store.delete("job2", ["report.json"])
    assert store.get("job2", "report.json") is None


def test_settings_read_comma_lists_and_redis_url(monkeypatch):
    monkeypatch.setenv("REDIS_URL", "redis://h:1/2")
    monkeypatch.setenv("CTP_API_KEYS", "a, b,,c")
    monkeypatch.setenv("CTP_MODELS", "random:tiny")
    settings = Settings()
    assert settings.redis_url == "redis://h:1/2"
    assert settings.api_keys == ["a", "b", "c"]
    # auto, the default, allows the default CLIP model too: what jobs that ask for guidance get
    assert settings.allowed_models == ["auto", "hf:openai/clip-vit-base-patch32", "random:tiny"]
    assert (settings.key_prefix, settings.served_queues, settings.storage_backend) == ("ctp", ["default"], "redis")


def test_queue_settings_and_the_old_queue_variable(monkeypatch):
    monkeypatch.setenv("CTP_QUEUE", "old")  # before named queues: rq queue and key prefix; now the prefix
    monkeypatch.setenv("CTP_QUEUES", "gpu, default,gpu")
    settings = Settings()
    assert (settings.key_prefix, settings.served_queues) == ("old", ["gpu", "default"])
    monkeypatch.setenv("CTP_KEY_PREFIX", "new")
    assert Settings().key_prefix == "new"
    monkeypatch.setenv("CTP_QUEUES", "gpu,GPU 2")
    with pytest.raises(ValueError, match="'GPU 2'"):
        Settings()


def test_the_worker_preloads_the_guide_its_jobs_get(monkeypatch):
    """The preload asks ``loaders.guide_for`` (one rule for which guide a config needs) for a default job's
    config on this worker, so a job's own ``guide_for`` is a cache hit, not a second load."""
    from ctp_core.guide import loaders
    from service.schemas import build_config
    from worker.main import _preload
    from worker.tasks import served

    loads, asked = [], []
    real_guide_for = loaders.guide_for
    monkeypatch.setattr(loaders, "_CACHE", {})
    monkeypatch.setattr(loaders, "load_guide", lambda s, **_: loads.append(s) or SimpleNamespace(runtime="torch"))
    monkeypatch.setattr(loaders, "guide_for", lambda config: asked.append(config) or real_guide_for(config))
    settings = Settings(model="random:tiny", models="", runtime="torch", device="cpu", threads=None)
    assert _preload(settings) == {"random:tiny": None}
    assert [(c.model, c.device, c.runtime, c.threads) for c in asked] == [("random:tiny", "cpu", "torch", None)]
    stored = build_config({"preset": "test"}, default_model=settings.model, allowed_models=settings.allowed_models)
    job = served(JobRecord(id=new_id(), owner="me", created_at=now(), config=stored), settings).config
    assert real_guide_for(job) is real_guide_for(asked[0]) and len(loads) == 1  # the job reuses the preload


ONNX_MODEL = "onnx:/nonexistent/ctp-onnx"  # forward only: ONNX Runtime on the CPU, no torch weights


@pytest.mark.parametrize(("device", "runtime", "threads", "model", "why"), [
    ("cpu", "torch", None, ONNX_MODEL, "runs only in ONNX Runtime on the CPU"),
    ("cuda", "auto", None, ONNX_MODEL, "runs only in ONNX Runtime on the CPU"),
    ("cuda", "onnx", None, "random:tiny", "runtime 'onnx' is ONNX Runtime on the CPU"),
    ("cpu", "auto", 300, "random:tiny", "threads: Input should be less than or equal to 256"),
])
def test_a_worker_refuses_a_job_its_settings_cannot_serve(device, runtime, threads, model, why):
    """The job's options were validated at submit under the default device and runtime; the worker's own
    (CTP_DEVICE, CTP_RUNTIME, CTP_THREADS) are checked when it takes the job, and a run they cannot serve is
    ``worker_cannot_serve``, saying the worker's settings and why, not an option error blamed on the client.
    An assembly's every stage is checked, not only the assembly's own config."""
    from ctp_core.errors import CtpError
    from service.jobs import AssemblyStep
    from service.schemas import build_config
    from worker.tasks import served

    settings = Settings(model="random:tiny", models=ONNX_MODEL, device=device, runtime=runtime, threads=threads)
    config = build_config({"preset": "test", "lambda_clip": 0, "model": model}, default_model=settings.model,
                          allowed_models=settings.allowed_models)
    align = JobRecord(id=new_id(), owner="me", created_at=now(), prompt="p", config=config)
    assembly = align.model_copy(update={"kind": "assemble", "config": AlignConfig(model="random:tiny"),
                                        "steps": [AssemblyStep(name="cup", file="cup.glb", config=config)]})
    for record in (align, assembly):
        with pytest.raises(CtpError) as refused:
            served(record, settings)
        assert refused.value.code == "worker_cannot_serve" and refused.value.field is None
        message = refused.value.message
        assert message.startswith(f"this worker runs jobs with device {device} (CTP_DEVICE), ") and why in message
        assert f"runtime {runtime} (CTP_RUNTIME) and cannot serve this one: " in message
    ok = Settings(model="random:tiny", models=ONNX_MODEL, device="cpu", runtime="onnx", threads=2)
    run = served(assembly, ok)
    assert (run.steps[0].config.device, run.steps[0].config.runtime, run.steps[0].config.threads) == ("cpu", "onnx", 2)
    assert run.steps[0].config == config.model_copy(update={"runtime": "onnx", "threads": 2})
    assert assembly.steps[0].config == config  # the stored record is not changed


def test_the_event_loop_reads_a_record_as_get_does(jobs, private_redis):
    """``own_job`` (every poll of a job) reads on the event loop's client through ``Jobs.get_async``, the
    same key and parsing as ``Jobs.get``."""
    import asyncio

    from redis import asyncio as aioredis

    record = queued(jobs)

    async def read(*job_ids: str):
        client = aioredis.Redis.from_url(private_redis.url)
        try:
            return [await jobs.get_async(client, job_id) for job_id in job_ids]
        finally:
            await client.aclose()

    assert asyncio.run(read(record.id, new_id())) == [jobs.get(record.id), None] and jobs.get(record.id) == record


def test_a_job_stops_once_its_record_is_gone_or_it_is_not_running(jobs):
    record = queued(jobs)
    assert jobs.should_stop(record.id)  # queued: not started by this worker
    jobs.redis.delete(jobs.record_key(record.id))
    assert jobs.should_stop(record.id)  # expired


def test_concurrent_submits_admit_exactly_the_limit(jobs):
    """Many threads submitting at once for one key, several times over: the limit is never exceeded (nor
    under-filled), since admission is one atomic step in Redis."""
    limit, racers = 4, 16

    def race(owner: str, start: threading.Barrier) -> JobRecord | TooManyJobs:
        start.wait()
        try:
            return queued(jobs, owner=owner, max_active=limit)
        except TooManyJobs as exc:
            return exc

    for trial in range(5):
        with ThreadPoolExecutor(racers) as pool:
            results = list(pool.map(race, [f"racer-{trial}"] * racers, [threading.Barrier(racers)] * racers))
        admitted = [r for r in results if isinstance(r, JobRecord)]
        assert len(admitted) == limit
        assert jobs.redis.scard(f"{jobs.prefix}:active:racer-{trial}") == limit
        assert all(r.retry_after_s == 60 for r in results if isinstance(r, TooManyJobs))  # none has an ETA yet


def test_a_refused_submit_says_when_a_slot_is_likely_free(jobs):
    """Retry-After of a 429: the soonest estimate of the key's running jobs, rounded up, within 1 to 60 s."""
    first, _ = queued(jobs, max_active=2), queued(jobs, max_active=2)
    with pytest.raises(TooManyJobs) as none_running:
        queued(jobs, max_active=2)
    assert none_running.value.retry_after_s == 60  # nothing has an estimate yet
    jobs.start(first.id, "w1")
    jobs.set_progress(first.id, Progress(kind="step", eta_s=7.2))
    with pytest.raises(TooManyJobs) as soon:
        queued(jobs, max_active=2)
    assert soon.value.retry_after_s == 8
    jobs.set_progress(first.id, Progress(kind="step", eta_s=0.1))
    assert jobs.retry_after("me") == 1


def test_progress_is_over_the_whole_job_one_share_per_alignment():
    """An assembly's (or copies') progress is one bar: step 5 of 10 of the second of two alignments is 75 %, not
    the 50 % of that alignment alone; a job of one alignment is its own fraction."""
    from ctp_core.progress import ProgressEvent
    from service.jobs import Stage
    from worker.tasks import progress_of

    event = ProgressEvent(kind="step", phase=1, phases=1, step=5, steps=10, restarts=1, elapsed_s=1.0, eta_s=1.0)
    assert progress_of(event, Stage(name="search", index=2, count=2, label="a stool")).fraction == 0.75
    assert progress_of(event, Stage(name="search", index=1, count=2, label="a toolbox")).fraction == 0.25
    assert progress_of(event).fraction == 0.5
