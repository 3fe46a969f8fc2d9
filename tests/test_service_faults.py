"""Faults with real processes: a SIGKILLed worker, a Redis restart between submit and pickup, a Redis SIGKILL
mid-job, a burst of concurrent jobs while a worker dies, cancel of queued and running jobs, the job timeout.
Jobs that must still be running when the fault hits use the test preset with a huge step budget (``LONG``), or
one that takes some seconds and then ends (``MID``). Every one asserts the final status of every job: none lost.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from pathlib import Path

import pytest
import redis

from service.client import Client, ServiceError
from service.embedded import EmbeddedRedis
from tests.conftest import Api, Worker, park_worker, service_env, wait_for, wait_ready
from tests.test_service import BALL, BOX, FAST, submit
from worker.outage import patient_redis

LONG = {**FAST, "steps": 100000}
MID = {**FAST, "steps": 40}  # some seconds of optimisation: a fault can hit it mid-run, and it still ends
SHORT = {**FAST, "steps": 20}
TERMINAL = ("succeeded", "failed", "canceled")


def status(api: Api, job_id: str) -> dict:
    return api.client.get(f"/jobs/{job_id}").json()


def wait_status(api: Api, job_id: str, statuses: tuple[str, ...], timeout_s: float = 60) -> dict:
    return wait_for(lambda: (job := status(api, job_id))["status"] in statuses and job, timeout_s,
                    f"job {job_id} to reach {'/'.join(statuses)}")


def wait_stepping(api: Api, job_id: str) -> dict:
    """Until the optimiser has taken a step: the job is truly mid-run."""
    return wait_for(lambda: (job := status(api, job_id))["progress"]["step"] > 0 and job, 90,
                    f"job {job_id} to take a step")


@pytest.fixture(scope="module")
def env(private_redis, tmp_path_factory):
    """Files on disk instead of in Redis here, so both storage back ends run end to end."""
    return service_env(private_redis.url, "faults", storage_dir=tmp_path_factory.mktemp("blobs"))


def test_cancel_running_and_queued_jobs(api, worker):
    running = submit(api, options=LONG).json()["id"]
    wait_stepping(api, running)
    queued = submit(api).json()["id"]  # one worker, busy: this one waits
    assert status(api, queued)["status"] == "queued"

    answer = api.client.delete(f"/jobs/{queued}")
    assert answer.status_code == 200 and answer.json()["status"] == "canceled"
    answer = api.client.delete(f"/jobs/{running}")
    assert answer.status_code == 202 and answer.json()["cancel_requested"]

    job = wait_status(api, running, ("canceled", "failed", "succeeded"), timeout_s=30)
    assert job["status"] == "canceled" and job["error"]["code"] == "canceled"
    assert job["progress"]["step"] < job["progress"]["steps"]  # stopped early, at a step boundary
    # The worker is free again, never ran the canceled queued job, and still serves.
    with Client(api.url) as client:
        after = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=FAST)
        messages = []
        final = client.wait(after["id"], on_progress=lambda j: messages.append(j["progress"]["message"]),
                            timeout_s=120)
        assert final["status"] == "succeeded" and len(messages) > 1
        assert len(client.download(after["id"], "result.glb")) > 0
        with pytest.raises(ServiceError) as refused:
            client.download(queued, "result.glb")
        assert (refused.value.status, refused.value.code) == (409, "job_not_ready")
    assert status(api, queued)["started_at"] is None


def test_job_timeout_fails_the_job(env, worker):
    impatient = Api({**env, "CTP_JOB_TIMEOUT_S": "3"})  # the timeout travels with the job
    try:
        job_id = submit(impatient, options=LONG).json()["id"]
        job = wait_status(impatient, job_id, ("failed", "succeeded", "canceled"), timeout_s=90)
        assert job["status"] == "failed" and job["error"]["code"] == "job_timeout", job
    finally:
        impatient.stop()


def test_killed_worker_loses_no_job(private_redis, tmp_path):
    """SIGKILL mid-job: the job's lease lapses and the reaper queues it again (attempt 2 of 2), behind the job
    queued meanwhile; the next worker runs both."""
    env = service_env(private_redis.url, "kill")
    api = Api(env)
    first = Worker(env, tmp_path / "first.log")
    second = None
    try:
        wait_ready(api)
        lost = submit(api, options=MID).json()["id"]
        wait_stepping(api, lost)
        waiting = submit(api).json()["id"]
        first.kill()

        job = wait_status(api, lost, ("queued",), timeout_s=30)
        assert (job["attempts"], job["started_at"], job["error"]) == (1, None, None)
        assert "missed its lease" in job["progress"]["message"] and "attempt 2 of 2" in job["progress"]["message"]
        assert status(api, waiting)["status"] == "queued"
        ready = api.client.get("/readyz")  # its heartbeat lapsed before the job's lease; within the grace
        assert (ready.status_code, ready.json()["status"], ready.json()["workers"]) == (200, "restarting", 0)

        second = Worker(env, tmp_path / "second.log")
        for job_id, attempts in ((waiting, 1), (lost, 2)):
            job = wait_status(api, job_id, TERMINAL, timeout_s=180)
            assert (job["status"], job["attempts"]) == ("succeeded", attempts), job
    finally:
        for process in (first, second):
            if process is not None:
                process.stop()
        api.stop()


def test_redis_restart_between_submit_and_pickup(tmp_path):
    """The guarantee: a 202 means the job is in Redis's append-only file; a clean Redis restart keeps it
    queued (with appendfsync everysec a machine crash may lose the last second of submissions)."""
    redis_server = EmbeddedRedis(tmp_path / "redis")
    redis_server.start()
    env = service_env(redis_server.url, "restart")
    api = Api(env)
    worker = None
    try:
        leave = park_worker(env)  # a live worker (heartbeat only): the API accepts the job, nobody takes it
        job_id = submit(api).json()["id"]
        leave()
        redis_server.stop(release=False)
        assert api.client.get(f"/jobs/{job_id}").json()["error"]["code"] == "redis_unavailable"
        redis_server.start()
        assert status(api, job_id)["status"] == "queued"  # the API reconnects on its own
        worker = Worker(env, tmp_path / "worker.log")
        assert wait_status(api, job_id, ("succeeded", "failed"), timeout_s=120)["status"] == "succeeded"
    finally:
        if worker is not None:
            worker.stop()
        api.stop()
        redis_server.stop()


# -- Redis outages, as a worker lives them ---------------------------------------------------------------

@pytest.fixture
def outage(monkeypatch, caplog):
    """A fresh process outage state, and the worker logger's records (``logs.configure`` stops its propagation)."""
    import worker.outage

    monkeypatch.setattr(worker.outage, "OUTAGE", worker.outage.Outage())
    logger = logging.getLogger("ctp.worker")
    logger.addHandler(caplog.handler)
    monkeypatch.setattr(logger, "level", logging.INFO)
    monkeypatch.setattr(logger, "propagate", False)  # as configured, and no record counted twice
    yield caplog
    logger.removeHandler(caplog.handler)


def test_a_worker_client_waits_out_an_outage_and_logs_it_once(tmp_path, outage):
    server = EmbeddedRedis(tmp_path / "redis")
    server.start()
    client = patient_redis(server.url, 30)
    try:
        client.set("k", "before")
        server.stop(release=False)
        answers = []
        reader = threading.Thread(target=lambda: answers.append(client.get("k")))
        reader.start()
        time.sleep(1.0)
        assert reader.is_alive() and not answers  # waiting, not failed
        server.start()
        reader.join(timeout=10)
        assert answers == [b"before"]  # the append-only file kept it
        client.set("k", "after")  # no outage: nothing more logged
        lines = [r.getMessage() for r in outage.records]
        assert len(lines) == 1 and lines[0].startswith("redis was unreachable for "), lines
    finally:
        client.close()
        server.stop()


def test_a_worker_client_gives_up_after_its_patience(tmp_path, outage):
    server = EmbeddedRedis(tmp_path / "redis")
    server.start()
    client = patient_redis(server.url, 1.0)
    try:
        client.ping()
        server.stop(release=False)
        started = time.monotonic()
        with pytest.raises(SystemExit) as gone:
            client.ping()
        assert gone.value.code == 1 and 1.0 <= time.monotonic() - started < 10
        with pytest.raises(SystemExit):  # every later call too, logged no more
            client.ping()
        lines = [r.getMessage() for r in outage.records]
        assert len(lines) == 1 and "giving up (CTP_REDIS_PATIENCE_S 1 s)" in lines[0], lines
    finally:
        client.close()
        server.stop()


def json_lines_only(log: Path) -> list[dict]:
    """Every line of a worker's log, parsed: one that is not JSON (a raw traceback) fails the test."""
    lines = log.read_text(errors="replace").splitlines()
    raw = [line for line in lines if not line.startswith("{")]
    assert not raw, "\n".join(raw[:20])
    return [json.loads(line) for line in lines]


def test_redis_sigkill_mid_job_loses_nothing(tmp_path):
    """SIGKILL the Redis under a running job and start it again a second later (what the supervisor of
    `ctp serve` does): the worker waits it out, the job goes on and succeeds on its first attempt, the job queued
    behind it too; the worker logs one JSON line for the outage and no traceback."""
    server = EmbeddedRedis(tmp_path / "redis")
    server.start()
    env = service_env(server.url, "redis-kill")
    api = Api(env)
    worker = Worker(env, tmp_path / "worker.log")
    try:
        wait_ready(api)
        running = submit(api, options=MID).json()["id"]
        wait_stepping(api, running)
        queued = submit(api).json()["id"]
        time.sleep(1.2)  # appendfsync everysec: the submission is on disk
        server.kill()
        time.sleep(1.0)
        server.start()
        for job_id in (running, queued):
            job = wait_status(api, job_id, TERMINAL, timeout_s=180)
            assert (job["status"], job["attempts"]) == ("succeeded", 1), job
        assert worker.process.poll() is None  # it rode the outage out
    finally:
        worker.stop()
        api.stop()
        server.stop()
    outages = [e for e in json_lines_only(tmp_path / "worker.log") if "redis" in e["msg"]]
    assert len(outages) == 1 and outages[0]["msg"].startswith("redis was unreachable for "), outages


def test_a_burst_while_a_worker_dies_loses_no_job(private_redis, tmp_path):
    """Six jobs submitted at once to two workers; one worker is SIGKILLed once it runs one: every job
    succeeds, the one it ran on its second attempt."""
    env = service_env(private_redis.url, "burst", max_active_jobs=100)
    api = Api(env)
    workers = [Worker(env, tmp_path / f"worker-{i}.log") for i in range(2)]
    try:
        wait_ready(api, workers=2, timeout_s=180)
        answers: list = []
        senders = [threading.Thread(target=lambda: answers.append(submit(api, options=SHORT))) for _ in range(6)]
        for sender in senders:
            sender.start()
        for sender in senders:
            sender.join()
        assert [a.status_code for a in answers] == [202] * 6, [a.text for a in answers]
        ids = [a.json()["id"] for a in answers]
        victim = wait_for(lambda: next((j for j in map(lambda i: status(api, i), ids)
                                        if j["status"] == "running" and j["progress"]["step"] > 0), None), 120,
                          "a job to be mid-run")
        store = redis.Redis.from_url(env["REDIS_URL"])
        name = json.loads(store.get(f"{env['CTP_KEY_PREFIX']}:job:{victim['id']}"))["worker"]  # host.pid
        store.close()
        next(w for w in workers if w.process.pid == int(name.rsplit(".", 1)[1])).kill()
        finals = [wait_status(api, job_id, TERMINAL, timeout_s=300) for job_id in ids]
        assert [j["status"] for j in finals] == ["succeeded"] * 6, finals
        assert sorted(j["attempts"] for j in finals)[-1] <= 2
        assert status(api, victim["id"])["attempts"] == 2
    finally:
        for w in workers:
            w.stop()
        api.stop()


def test_a_worker_whose_redis_stays_gone_exits_1_without_a_traceback(tmp_path):
    """Past CTP_REDIS_PATIENCE_S the worker leaves (status 1, for its supervisor to see), saying so in one line."""
    server = EmbeddedRedis(tmp_path / "redis")
    server.start()
    env = service_env(server.url, "redis-gone", redis_patience_s=2)
    api = Api(env)
    worker = Worker(env, tmp_path / "worker.log")
    try:
        wait_ready(api)
        server.kill()
        assert worker.process.wait(timeout=60) == 1
    finally:
        worker.stop()
        api.stop()
        server.stop()
    ours = [e["msg"] for e in json_lines_only(tmp_path / "worker.log") if e["logger"] == "ctp.worker"]
    assert len(ours) == 1 and "giving up (CTP_REDIS_PATIENCE_S 2 s); the worker exits" in ours[0], ours
