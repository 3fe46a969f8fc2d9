"""Webhooks, ``Idempotency-Key`` and ``Prefer: wait`` against a real Redis, uvicorn and ``ctp worker``: deliveries
are received by a real HTTP server on loopback and their signatures checked by an independent implementation
(the few lines a receiver would write); a 500 is retried, a redirect is not followed, progress comes at most once a
second; private addresses are refused unless allowed; concurrent submits with one key make one job."""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import threading
import time
import uuid
from datetime import datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import httpx
import pytest

from service.client import Client, ServiceError
from service.submit import wait_preference
from service.webhooks import Delivery, WebhookInvalid, check_url, resolve, signature
from tests.conftest import Api, park_worker, service_env, wait_for
from tests.test_service import BALL, BOX

SECRET = "whsec_" + base64.b64encode(b"ctp test webhook secret!").decode()
FAST = {"preset": "test", "model": "random:tiny"}
ALPHA, BETA = ({"Authorization": f"Bearer {k}"} for k in ("alpha", "beta"))


def verify(secret: str, headers, body: bytes, received_at: float) -> dict:
    """What a receiver does (docs/service.md): HMAC-SHA256 of "{id}.{timestamp}.{body}" with the base64-decoded
    secret, compared with each "v1,<base64>" of the signature header; a timestamp stale when it was received (at
    ``received_at``) is refused."""
    key = base64.b64decode(secret.removeprefix("whsec_"))
    signed = f"{headers['webhook-id']}.{headers['webhook-timestamp']}.".encode() + body
    expected = base64.b64encode(hmac.new(key, signed, hashlib.sha256).digest()).decode()
    if abs(received_at - int(headers["webhook-timestamp"])) > 300:
        raise ValueError("stale webhook")
    if not any(hmac.compare_digest(expected, sig.partition(",")[2]) for sig in headers["webhook-signature"].split()):
        raise ValueError("bad signature")
    return json.loads(body)


class Receiver:
    """A threaded HTTP server on 127.0.0.1 that records every POST. ``/fail-once`` answers 500 to the first
    delivery of each completed event, ``/redirect`` answers 307 to ``/ok``, anything else 200."""

    def __init__(self):
        self.deliveries: list[dict] = []
        self.lock = threading.Lock()
        failed: set[str] = set()
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self):
                body = self.rfile.read(int(self.headers["content-length"]))
                status = 200
                if self.path == "/redirect":
                    status = 307
                elif self.path == "/fail-once" and json.loads(body)["type"] == "completed":
                    with receiver.lock:
                        if self.headers["webhook-id"] not in failed:
                            failed.add(self.headers["webhook-id"])
                            status = 500
                with receiver.lock:
                    receiver.deliveries.append({"at": time.time(), "path": self.path, "body": body,
                                                "headers": {k.lower(): v for k, v in self.headers.items()},
                                                "status": status})
                self.send_response(status)
                if status == 307:
                    self.send_header("Location", "/ok")
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, *args):
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}{path}"

    def of(self, job_id: str, path: str | None = None) -> list[dict]:
        """Deliveries about a job (on ``path``), in arrival order, each with its verified payload."""
        with self.lock:
            seen = list(self.deliveries)
        out = []
        for d in seen:
            payload = verify(SECRET, d["headers"], d["body"], d["at"])
            if payload["data"]["id"] == job_id and (path is None or d["path"] == path):
                out.append({**d, "payload": payload})
        return out

    def stop(self):
        self.server.shutdown()
        self.server.server_close()


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "hooks", api_keys="alpha,beta", max_active_jobs=50, webhook_secret=SECRET,
                       webhook_allow_private="true", webhook_retry_s=5)


@pytest.fixture(scope="module")
def receiver():
    server = Receiver()
    yield server
    server.stop()


def post(api, path="/align", headers=ALPHA, prompt="a ball on top of a box", source=("ball.glb", BALL), **fields):
    data = {"prompt": prompt, "options": json.dumps(FAST), **fields}
    return api.client.post(path, files={"target": ("box.glb", BOX), "source": source}, data=data, headers=headers)


def _seconds(stamp: str) -> float:
    return datetime.fromisoformat(stamp.replace("Z", "+00:00")).timestamp()


def settled(api, job_id, timeout_s=120):
    """The job once it ended and its webhook has nothing pending."""
    def done():
        job = api.client.get(f"/jobs/{job_id}", headers=ALPHA).json()
        return job["status"] in ("succeeded", "failed", "canceled") and job["webhook"]["pending"] == 0 and job
    return wait_for(done, timeout_s, f"job {job_id} and its webhook deliveries")


def test_deliveries_are_signed_retried_after_a_500_and_progress_is_throttled(api, worker, receiver):
    accepted = post(api, webhook=receiver.url("/fail-once"), webhook_events="start,progress,completed")
    assert accepted.status_code == 202, accepted.text
    changes = []  # the job's progress as its event stream shows it: every change the worker wrote

    def follow():
        with api.client.stream("GET", accepted.json()["links"]["events"], headers=ALPHA, timeout=120) as stream:
            changes.extend(json.loads(line[6:])["progress"] for line in stream.iter_lines() if line[:6] == "data: ")

    follower = threading.Thread(target=follow)
    follower.start()
    job = settled(api, accepted.json()["id"])
    follower.join()
    assert job["status"] == "succeeded"
    got = receiver.of(job["id"])  # every one verified
    types = [d["payload"]["type"] for d in sorted(got, key=lambda d: _seconds(d["payload"]["timestamp"]))]
    assert types[0] == "start" and types.count("start") == 1  # arrival order is not guaranteed; event times are
    assert [d["payload"]["data"]["status"] for d in got if d["payload"]["type"] == "start"] == ["running"]
    # completed: a 500, then the same event (same webhook-id) again after the back-off, signed anew, 200
    completed = [d for d in got if d["payload"]["type"] == "completed"]
    assert [d["status"] for d in completed] == [500, 200]
    assert completed[0]["headers"]["webhook-id"] == completed[1]["headers"]["webhook-id"]
    assert completed[1]["at"] - completed[0]["at"] >= 0.9
    assert completed[1]["payload"]["data"]["status"] == "succeeded"
    # progress: at most one a second (the events' own times), though the worker writes progress every 0.5 s
    progress = [d["payload"] for d in got if d["payload"]["type"] == "progress"]
    running = {json.dumps(p, sort_keys=True) for p in changes if p["kind"] not in ("queued", "done")}
    assert 0 < len(progress) < len(running), (types, len(running))
    stamps = sorted(_seconds(p["timestamp"]) for p in progress)
    assert all(b - a >= 0.99 for a, b in zip(stamps, stamps[1:], strict=False)), stamps
    assert len({d["headers"]["webhook-id"] for d in got}) == len(got) - 1  # one retry: the completed event
    assert job["webhook"] == {"url": receiver.url("/fail-once"), "events": ["start", "progress", "completed"],
                              "delivered": len(got) - 1, "failed": 0, "pending": 0, "attempts": len(got),
                              "last_status": 200, "last_error": None}


def test_redirects_are_not_followed_and_retries_end(api, worker, receiver):
    """A 3xx is a failed attempt (the Location is never called); retries stop CTP_WEBHOOK_RETRY_S (5 s here)
    after the event, and the job says so."""
    accepted = post(api, webhook=receiver.url("/redirect"))
    job = settled(api, accepted.json()["id"])
    tries = receiver.of(job["id"])
    assert [d["payload"]["type"] for d in tries] == ["completed"] * len(tries) and len(tries) >= 2
    assert len({d["headers"]["webhook-id"] for d in tries}) == 1
    assert not [d for d in receiver.deliveries if d["path"] == "/ok"]
    hook = job["webhook"]
    assert (hook["delivered"], hook["failed"], hook["attempts"], hook["last_status"]) == (0, 1, len(tries), 307)
    assert "redirects are not followed" in hook["last_error"]


def test_prefer_wait_answers_the_finished_job(api, worker, receiver):
    """Prefer: wait=600 is taken as 60; the job ends well within it: 200 with the finished job. The Python
    client's wait=, webhook= and idempotency_key= send the same."""
    started = time.monotonic()
    answer = post(api, headers={**ALPHA, "Prefer": "respond-async, wait=600"})
    assert answer.status_code == 200, answer.text
    assert answer.headers["Preference-Applied"] == "wait=60" and time.monotonic() - started < 60
    assert answer.json()["status"] == "succeeded" and answer.json()["progress"]["fraction"] == 1.0
    with Client(api.url, api_key="alpha") as client:
        key = str(uuid.uuid4())
        job = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=FAST, wait=60,
                            webhook=receiver.url("/ok"), webhook_events=["start", "completed"], idempotency_key=key)
        assert job["status"] == "succeeded" and job["webhook"]["events"] == ["start", "completed"]
        again = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=FAST,
                              webhook=receiver.url("/ok"), webhook_events=["start", "completed"], idempotency_key=key)
        assert again["id"] == job["id"]
        with pytest.raises(ServiceError) as conflict:
            client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball beside a box", options=FAST,
                          idempotency_key=key)
        assert (conflict.value.status, conflict.value.code) == (409, "idempotency_conflict")
    wait_for(lambda: [d["payload"]["type"] for d in receiver.of(job["id"])] == ["start", "completed"], 30,
             "the client's job's start and completed deliveries")


def test_idempotent_submits_make_one_job_per_key_and_owner(api, worker):
    key = str(uuid.uuid4())
    first = post(api, headers={**ALPHA, "Idempotency-Key": key})
    assert first.status_code == 202, first.text
    again = post(api, headers={**ALPHA, "Idempotency-Key": key})
    assert again.status_code == 200 and again.json()["id"] == first.json()["id"]
    assert set(again.json()) >= {"status", "progress", "created_at", "links"}  # the job, as GET /jobs/{id}
    other = post(api, headers={**ALPHA, "Idempotency-Key": key}, source=("ball2.glb", BALL))  # a file name differs
    assert (other.status_code, other.json()["error"]["code"]) == (409, "idempotency_conflict")
    assert other.json()["error"]["field"] == "Idempotency-Key"
    theirs = post(api, headers={**BETA, "Idempotency-Key": key})  # keys are per API key
    assert theirs.status_code == 202 and theirs.json()["id"] != first.json()["id"]
    # a refused submit does not keep its key: fixed, the same key queues a job
    fresh = str(uuid.uuid4())
    refused = post(api, headers={**ALPHA, "Idempotency-Key": fresh}, prompt="\x07")
    assert refused.json()["error"]["code"] == "invalid_prompt"
    assert post(api, headers={**ALPHA, "Idempotency-Key": fresh}).status_code == 202
    bad = post(api, headers={**ALPHA, "Idempotency-Key": "has space"})
    assert (bad.status_code, bad.json()["error"]["code"]) == (400, "invalid_idempotency_key")


def test_concurrent_submits_with_one_key_make_one_job(api, worker):
    key = str(uuid.uuid4())
    before = api.client.get("/jobs", headers=ALPHA).json()["total"]
    barrier = threading.Barrier(2)
    answers: list[httpx.Response] = []

    spans: list[tuple[float, float]] = []

    def send():
        with httpx.Client(base_url=api.url, timeout=60) as client:
            barrier.wait()
            started = time.monotonic()
            answers.append(client.post("/align", files={"target": ("box.glb", BOX), "source": ("ball.glb", BALL)},
                                       data={"prompt": "a ball on top of a box", "options": json.dumps(FAST)},
                                       headers={**ALPHA, "Idempotency-Key": key}))
            spans.append((started, time.monotonic()))

    threads = [threading.Thread(target=send) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert max(s for s, _ in spans) < min(e for _, e in spans)  # the two requests overlapped
    assert sorted(a.status_code for a in answers) == [200, 202], [a.text for a in answers]
    assert answers[0].json()["id"] == answers[1].json()["id"]
    assert api.client.get("/jobs", headers=ALPHA).json()["total"] == before + 1


def test_assemble_takes_a_webhook_a_key_and_a_wait(api, worker, receiver):
    plan = json.dumps([{"file": "ball.glb", "prompt": "a ball on top of a box"}])
    headers = {**ALPHA, "Idempotency-Key": str(uuid.uuid4()), "Prefer": "wait=60"}

    def send():
        return api.client.post("/assemble", files=[("base", ("box.glb", BOX)), ("source", ("ball.glb", BALL))],
                               data={"plan": plan, "options": json.dumps(FAST), "webhook": receiver.url("/ok")},
                               headers=headers)

    done = send()
    assert done.status_code == 200 and done.json()["status"] == "succeeded", done.text
    assert send().json()["id"] == done.json()["id"]
    delivered = wait_for(lambda: receiver.of(done.json()["id"]), 30, "the assembly's completed delivery")
    assert [d["payload"]["type"] for d in delivered] == ["completed"]


@pytest.fixture(scope="module")
def strict(private_redis):
    """An API that refuses private webhook addresses, with a parked worker: jobs are accepted and stay queued."""
    env = service_env(private_redis.url, "hooks-strict", webhook_secret=SECRET)
    leave = park_worker(env)
    server = Api(env)
    yield server
    server.stop()
    leave()


@pytest.mark.parametrize(("url", "code"), [
    ("http://127.0.0.1:9/hook", "webhook_url_refused"), ("http://localhost/hook", "webhook_url_refused"),
    ("http://10.1.2.3/", "webhook_url_refused"), ("http://169.254.169.254/latest", "webhook_url_refused"),
    ("http://[::1]/", "webhook_url_refused"), ("http://[::ffff:192.168.0.1]/", "webhook_url_refused"),
    ("http://224.0.0.251/", "webhook_url_refused"), ("http://0.0.0.0/", "webhook_url_refused"),
    ("http://100.64.0.1/", "webhook_url_refused"), ("ftp://8.8.8.8/", "invalid_webhook"),
    ("http:///path", "invalid_webhook"), ("http://8.8.8.8/a b", "invalid_webhook"),
])
def test_webhook_urls_are_checked_at_submit(strict, url, code):
    answer = post(strict, headers=None, webhook=url)
    error = answer.json()["error"]
    assert (answer.status_code, error["code"], error["field"]) == (422, code, "webhook")


def test_submit_refusals_and_a_wait_that_runs_out(strict, private_redis):
    events = post(strict, headers=None, webhook="http://8.8.8.8/", webhook_events="start,finished")
    assert (events.status_code, events.json()["error"]["code"]) == (422, "invalid_webhook")
    orphan = post(strict, headers=None, webhook_events="start")
    assert (orphan.status_code, orphan.json()["error"]["code"]) == (400, "invalid_field")
    # the job stays queued (no worker takes it): the wait runs out, 202, honoured
    started = time.monotonic()
    queued = post(strict, headers={"Prefer": "wait=1"})
    assert queued.status_code == 202 and queued.headers["Preference-Applied"] == "wait=1"
    assert queued.json()["status"] == "queued" and time.monotonic() - started >= 1.0
    ignored = post(strict, headers={"Prefer": "wait=soon"})  # malformed: ignored, as RFC 7240 says
    assert ignored.status_code == 202 and "Preference-Applied" not in ignored.headers
    no_secret = Api(service_env(private_redis.url, "hooks-off"))
    try:
        off = post(no_secret, headers=None, webhook="http://8.8.8.8/")
        assert (off.status_code, off.json()["error"]["code"]) == (422, "webhooks_disabled")
    finally:
        no_secret.stop()


def test_delivery_rechecks_the_address(strict, receiver):
    """A host that resolves to a private address by the time of delivery is not called."""
    from service.delivery import Deliverer

    deliverer = Deliverer(strict.server.config.app.state.jobs, b"k" * 16, allow_private=False, retry_s=5,
                          timeout_s=2)
    try:
        delivery = Delivery(id="msg_x", job_id="0" * 32, event="completed", url=receiver.url("/ok"),
                            created=time.time(), record="{}")
        before = len(receiver.deliveries)
        status, error = deliverer._post(delivery, b"{}")
        assert status is None and "not a public address" in error and len(receiver.deliveries) == before
    finally:
        deliverer.pool.shutdown()
        deliverer.http.close()


def test_signature_matches_the_standard_webhooks_example():
    """The example of the Standard Webhooks specification (its reference libraries' test vector)."""
    from service.webhooks import secret_bytes

    key = secret_bytes("whsec_MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw")
    assert signature(key, "msg_p5jXN8AQM9LWM0D4loKWxJek", 1614265330, b'{"test": 2432232314}') == \
        "v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE="


@pytest.mark.parametrize(("header", "seconds"), [
    (None, None), ("wait=5", 5), ("respond-async, wait=10", 10), ("WAIT = 7 ; x=1", 7), ('wait="3"', 3),
    ("wait=61", 60), ("wait=-1", None), ("wait=1.5", None), ("wait", None), ("return=minimal", None),
])
def test_prefer_wait_parsing(header, seconds):
    assert wait_preference(header) == seconds


def test_url_checks_without_http():
    assert check_url("https://example.com/hook?x=1") == ("example.com", 443)
    assert resolve("127.0.0.1", 80, allow_private=True) == ["127.0.0.1"]
    with pytest.raises(WebhookInvalid) as refused:
        resolve("64:ff9b::7f00:1", 80, allow_private=False)  # NAT64 of 127.0.0.1
    assert refused.value.code == "webhook_url_refused"


def test_events_are_queued_with_the_change_that_caused_them(private_redis):
    """Start, progress (one a second however often it changes) and completed go to the outbox in the transaction
    that changes the job, from a worker's calls or the API's (a queued job canceled)."""
    import redis

    from ctp_core.config import AlignConfig
    from service.jobs import JobRecord, Jobs, Progress, new_id, now
    from service.storage import RedisStorage
    from service.webhooks import Webhook

    client = redis.Redis.from_url(private_redis.url)
    prefix = f"outbox-{uuid.uuid4().hex[:8]}"
    jobs = Jobs(client, RedisStorage(client, prefix, 600), prefix=prefix, ttl_s=600, job_timeout_s=60, lease_s=5)

    def submitted(events):
        record = JobRecord(id=new_id(), owner="me", created_at=now(), prompt="p", config=AlignConfig(),
                           webhook=Webhook(url="http://example.com/", events=events))
        return jobs.submit(record, {"target": b"t", "source": b"s"}, 10)

    job = submitted(["start", "progress", "completed"])
    jobs.start(job.id, "w1")
    for step in range(1, 6):
        jobs.set_progress(job.id, Progress(kind="step", step=step, steps=5))
    jobs.finish(job.id, "succeeded")
    due = jobs.outbox.claim(10, hold_s=60)
    assert [d.event for d in due] == ["start", "progress", "completed"]
    assert [JobRecord.model_validate_json(d.record).status for d in due] == ["running", "running", "succeeded"]
    assert JobRecord.model_validate_json(due[1].record).progress.step == 1  # the first; the next four were < 1 s
    assert jobs.get(job.id).webhook.pending == 3 and jobs.outbox.claim(10, hold_s=60) == []  # claimed: hidden
    canceled = submitted(["completed"])
    jobs.cancel(canceled.id)
    (delivery,) = jobs.outbox.claim(10, hold_s=60)
    assert (delivery.job_id, delivery.event) == (canceled.id, "completed")
    assert jobs.delivery_done(delivery, delivered=True, retry_at=None, status=204, error=None).webhook.model_dump(
        include={"delivered", "pending", "attempts", "last_status"}) == {"delivered": 1, "pending": 0, "attempts": 1,
                                                                          "last_status": 204}
    assert not jobs.redis.exists(f"{jobs.prefix}:webhook:{delivery.id}")  # settled with the count, in one step
    assert jobs.redis.zscore(f"{jobs.prefix}:webhooks", delivery.id) is None
    client.close()
