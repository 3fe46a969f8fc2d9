"""No outage while a worker heals: a worker seen within the grace (``CTP_WORKER_GRACE_S``) still counts while
none is live, so a job submitted during a restart is accepted (202, queued) and runs once the worker is back;
``/readyz`` says ``restarting`` with ``since_s``, and 503 ``no_worker`` only once no worker has been seen for
longer than the grace. Timings here are generous: the machine running the tests may be loaded."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid

import pytest
import redis

from ctp.cmd_serve import stop_processes
from service.jobs import Jobs
from service.settings import Settings
from service.storage import RedisStorage
from service.supervisor import Supervisor
from tests.conftest import REPO, Api, service_env, wait_for, wait_ready
from tests.test_service import submit


def jobs_with_grace(url: str, prefix: str, *, lease_s: int, grace_s: float) -> Jobs:
    client = redis.Redis.from_url(url)
    return Jobs(client, RedisStorage(client, prefix, 600), prefix=prefix, ttl_s=600, job_timeout_s=60,
                lease_s=lease_s, worker_grace_s=grace_s)


@pytest.fixture
def jobs(private_redis):
    store = jobs_with_grace(private_redis.url, f"grace-{uuid.uuid4().hex[:8]}", lease_s=1, grace_s=30)
    yield store
    store.redis.close()


# -- Jobs.unavailable with and without last-seen records -------------------------------------------------

def test_without_a_grace_a_worker_that_left_is_gone_at_once(private_redis):
    jobs = jobs_with_grace(private_redis.url, f"grace-{uuid.uuid4().hex[:8]}", lease_s=5, grace_s=0)
    jobs.heartbeat("a", None, {"random:tiny": None})
    assert jobs.unavailable("random:tiny") is None
    jobs.workers.gone("a")
    assert jobs.workers.seen() == {}
    assert jobs.unavailable("random:tiny").code == "no_worker"
    assert not jobs.redis.keys(f"{jobs.prefix}:seen*")  # nothing written without a grace


def test_a_worker_seen_within_the_grace_still_counts_when_none_is_live(jobs):
    assert jobs.unavailable("random:tiny").code == "no_worker"  # never seen: no grace to give
    assert jobs.workers.seen() == {}
    jobs.heartbeat("a", None, {"random:tiny": None, "hf:big": "weights for 'big' are not in the cache"})
    jobs.workers.gone("a")  # a clean exit does not end the grace
    assert jobs.workers.live() == {}
    seen = jobs.workers.seen()
    assert list(seen) == ["a"] and 0.0 <= seen["a"].since_s < 5
    assert seen["a"].models == {"random:tiny": None, "hf:big": "weights for 'big' are not in the cache"}
    assert jobs.unavailable("random:tiny") is None and jobs.unavailable(None) is None
    # What the last-seen worker could not run is still refused, with its reason.
    big = jobs.unavailable("hf:big")
    assert (big.code, big.field) == ("model_unavailable", "options.model")
    assert big.message == ("no recently seen worker (none is live now) can run model 'hf:big': "
                           "weights for 'big' are not in the cache")
    assert "no recently seen worker offers it" in jobs.unavailable("random:ViT-B-32").message
    time.sleep(0.6)
    assert jobs.workers.seen()["a"].since_s > seen["a"].since_s  # time since it was last seen grows


def test_a_live_worker_decides_over_the_last_seen_ones(jobs):
    jobs.heartbeat("a", None, {"random:tiny": None})
    jobs.workers.gone("a")
    jobs.heartbeat("b", None, {"random:tiny": "weights missing"})  # live, but cannot run it
    assert jobs.unavailable("random:tiny").message == "no live worker can run model 'random:tiny': weights missing"
    wait_for(lambda: not jobs.workers.live(), 10, "b's lease (1 s) to lapse")
    assert jobs.unavailable("random:tiny") is None  # none live: a seen worker could run it
    assert sorted(jobs.workers.seen()) == ["a", "b"]


def test_a_queue_whose_workers_restart_keeps_accepting_while_other_queues_are_live(jobs):
    jobs.heartbeat("g", None, {"random:tiny": None}, ["gpu"])
    jobs.heartbeat("c", None, {"random:tiny": None})
    jobs.workers.gone("g")  # the only gpu worker restarts; the default queue's is live
    assert list(jobs.workers.live()) == ["c"]
    assert jobs.unavailable("random:tiny", queue="gpu") is None  # judged by the gpu worker seen within the grace
    assert jobs.unavailable("hf:big", queue="gpu").message == (
        "no recently seen worker of queue 'gpu' (none is live now) can run model 'hf:big': no recently seen worker "
        "of queue 'gpu' offers it")
    assert jobs.unavailable(None, queue="tpu").code == "queue_not_served"


def test_past_the_grace_no_worker_again_and_records_are_forgotten(private_redis):
    jobs = jobs_with_grace(private_redis.url, f"grace-{uuid.uuid4().hex[:8]}", lease_s=1, grace_s=3)
    jobs.heartbeat("a", None, {"random:tiny": None})
    wait_for(lambda: not jobs.workers.live(), 10, "the lease (1 s) to lapse", interval_s=0.05)
    assert jobs.unavailable("random:tiny") is None  # lease lapsed, still within the grace
    wait_for(lambda: not jobs.workers.seen(), 10, "the grace (3 s) to pass")
    assert jobs.unavailable("random:tiny").code == "no_worker"
    assert not jobs.redis.exists(f"{jobs.prefix}:seen")  # the name list expires with the last record


def test_the_grace_is_a_setting_read_by_the_workers_jobs(private_redis):
    assert Settings().worker_grace_s == 90
    store = Jobs.from_settings(Settings(redis_url=private_redis.url, worker_grace_s=7))
    assert store.workers.worker_grace_s == 7
    store.redis.close()


# -- through the API -------------------------------------------------------------------------------------

def readyz(api: Api) -> tuple[int, dict]:
    answer = api.client.get("/readyz")
    return answer.status_code, answer.json()


def test_readyz_restarting_then_no_worker_after_the_grace(private_redis):
    """A worker that exits cleanly: within the grace /readyz is 200 restarting and jobs are accepted; once no
    worker has been seen for longer than the grace, 503 no_worker for both."""
    env = service_env(private_redis.url, f"grace-api-{uuid.uuid4().hex[:6]}")
    api = Api(env)
    # a grace long enough for a submit's upload check (a fresh loader process) on a loaded machine
    jobs = jobs_with_grace(private_redis.url, env["CTP_KEY_PREFIX"], lease_s=2, grace_s=10)
    try:
        jobs.heartbeat("w", None, {"random:tiny": None})  # what a worker's heartbeat writes
        code, body = readyz(api)
        assert (code, body["status"], body["since_s"]) == (200, "ready", None)
        jobs.workers.gone("w")
        left = time.monotonic()
        code, body = readyz(api)
        assert (code, body["status"], body["workers"], body["models"]) == (200, "restarting", 0, ["random:tiny"])
        assert 0 <= body["since_s"] <= 10
        accepted = submit(api)
        assert accepted.status_code == 202, accepted.text
        assert api.client.get(f"/jobs/{accepted.json()['id']}").json()["status"] == "queued"

        wait_for(lambda: readyz(api)[0] == 503, 40, "the grace (10 s) to pass", interval_s=0.2)
        assert time.monotonic() - left > 2  # not ended early by the clean exit
        code, body = readyz(api)
        assert (code, body["error"]["code"]) == (503, "no_worker")
        refused = submit(api)
        assert (refused.status_code, refused.json()["error"]["code"]) == (503, "no_worker")
        api.client.delete(f"/jobs/{accepted.json()['id']}")
    finally:
        jobs.redis.close()
        api.stop()


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")
def test_a_job_submitted_while_the_supervised_worker_restarts_is_accepted_and_succeeds(private_redis, tmp_path):
    """``ctp serve``'s set-up (a supervisor restarting ``ctp worker`` processes) with a short lease and a
    long first back-off, so the restart surely spans a window with no live worker: SIGKILL the worker,
    submit at once and while /readyz says restarting; both jobs are accepted and succeed on the new worker."""
    env = service_env(private_redis.url, f"grace-heal-{uuid.uuid4().hex[:6]}", lease_s=2, worker_grace_s=60)
    api = Api(env)
    log = open(tmp_path / "workers.log", "ab")  # noqa: SIM115 - closed below
    supervisor = Supervisor(lambda: subprocess.Popen([sys.executable, "-m", "ctp", "worker"], env=env, cwd=REPO,
                                                     stdout=log, stderr=subprocess.STDOUT), 1,
                            worker_backoff_s=8.0)
    try:
        supervisor.start()
        wait_ready(api, timeout_s=120)
        first = supervisor.processes[0]
        os.kill(first.pid, signal.SIGKILL)
        at_once = submit(api)
        assert at_once.status_code == 202, at_once.text

        restarting = []  # /readyz while no worker is live (lease 2 s lapsed, restart 8 s after the death)
        def watch():
            code, body = readyz(api)
            if body.get("status") == "restarting":
                restarting.append(body)
            return code == 200 and body["status"] == "ready" and body["workers"] == 1 and restarting
        during = []
        def submit_while_restarting():
            if restarting and not during:
                during.append(submit(api))
            return watch()
        wait_for(submit_while_restarting, 180, "the worker to be restarted", interval_s=0.25)

        assert restarting and all(r["workers"] == 0 and r["models"] == ["random:tiny"] for r in restarting)
        since = [r["since_s"] for r in restarting]
        assert since == sorted(since) and since[-1] > since[0], since  # seconds since last seen, growing
        assert since[-1] < 60
        assert during and during[0].status_code == 202, during[0].text
        assert supervisor.processes[0] is not first and first.poll() is not None
        for job_id in (at_once.json()["id"], during[0].json()["id"]):
            job = wait_for(lambda job_id=job_id: (j := api.client.get(f"/jobs/{job_id}").json())["status"]
                           in ("succeeded", "failed", "canceled") and j, 180, f"job {job_id} to end")
            assert job["status"] == "succeeded", job
    finally:
        stop_processes(supervisor.stop(), grace_s=15)
        log.close()
        api.stop()
