"""Faults with real processes: a SIGKILLed worker, a Redis restart between submit and pickup, cancel of
queued and running jobs, the job timeout. Jobs that must still be running when the fault hits use the
test preset with a huge step budget."""

from __future__ import annotations

import pytest

from service.client import Client, ServiceError
from service.embedded import EmbeddedRedis
from tests.conftest import Api, Worker, park_worker, service_env, wait_for, wait_ready
from tests.test_service import BALL, BOX, FAST, submit

LONG = {**FAST, "steps": 100000}


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


def test_killed_worker_fails_its_job_and_loses_no_other(private_redis, tmp_path):
    """SIGKILL mid-job: the job's lease lapses and the reaper fails it (worker_lost, not retried); the job
    queued behind it is untouched and runs on the next worker."""
    env = service_env(private_redis.url, "kill")
    api = Api(env)
    first = Worker(env, tmp_path / "first.log")
    second = None
    try:
        wait_ready(api)
        doomed = submit(api, options=LONG).json()["id"]
        wait_stepping(api, doomed)
        waiting = submit(api).json()["id"]
        first.kill()

        job = wait_status(api, doomed, ("failed", "succeeded", "canceled"), timeout_s=30)
        assert job["status"] == "failed" and job["error"]["code"] == "worker_lost", job
        assert "not retried" in job["error"]["message"]
        assert status(api, waiting)["status"] == "queued"
        ready = api.client.get("/readyz")  # its heartbeat lapsed with the job's lease; within the grace
        assert (ready.status_code, ready.json()["status"], ready.json()["workers"]) == (200, "restarting", 0)

        second = Worker(env, tmp_path / "second.log")
        assert wait_status(api, waiting, ("succeeded", "failed"), timeout_s=120)["status"] == "succeeded"
        assert status(api, doomed)["status"] == "failed"  # the reaped job stays failed
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
