"""Uploads and results in an S3-compatible object store (``S3Storage``) against a real S3-protocol server on
loopback (moto's standalone server, ``s3_server``), and workers anywhere: the API and workers as separate
processes, each in its own directory with its own home, cache and temporary folder, sharing only Redis and the
store, on named queues; one worker SIGKILLed mid-job."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx
import pytest
import redis

from ctp.cmd_serve import stop_processes
from service.client import Client, ServiceError
from service.embedded import free_port
from service.jobs import OUTPUTS, Jobs, alternative_blob
from service.storage import S3Storage, StorageUnavailable
from tests.conftest import REPO, Api, Worker, park_worker, service_env, wait_for
from tests.test_service import BALL, BOX, FAST, submit
from tests.test_service_faults import MID, status, wait_status, wait_stepping


def storage(s3_server, prefix: str | None = None, ttl_s: int = 3600, **kwargs) -> S3Storage:
    return S3Storage(s3_server.bucket, prefix or f"unit-{uuid.uuid4().hex[:8]}/", ttl_s,
                     endpoint_url=s3_server.url, **kwargs)


def objects(s3_server, prefix: str) -> list[str]:
    """The keys under ``prefix``, relative to it, as the store lists them."""
    pages = s3_server.client().get_paginator("list_objects_v2").paginate(Bucket=s3_server.bucket, Prefix=prefix)
    return sorted(o["Key"].removeprefix(prefix) for page in pages for o in page.get("Contents", []))


# -- the back end on its own ---------------------------------------------------------------------------------

def test_round_trip_delete_and_presigned_urls(s3_server):
    store = storage(s3_server)
    store.put("job1", "result.glb", b"glb bytes")
    assert store.get("job1", "result.glb") == b"glb bytes"
    assert store.get("job1", "missing") is None and store.get("nojob", "result.glb") is None
    with pytest.raises(ValueError):
        store.put("../x", "a", b"")
    url = store.url("job1", "result.glb", 60, media_type="model/gltf-binary", filename="job1-result.glb")
    fetched = httpx.get(url)  # no credentials: the URL carries its signature
    assert (fetched.status_code, fetched.content) == (200, b"glb bytes")
    assert fetched.headers["content-disposition"] == 'attachment; filename="job1-result.glb"'
    assert fetched.headers["content-type"] == "model/gltf-binary"
    assert httpx.get(url.replace("result.glb", "report.json")).status_code == 403  # signed for one object
    assert store.url("job1", "missing", 60, media_type="x/y", filename="f") is None  # the API's 404 then
    store.delete("job1", ["result.glb", "never-written"])
    assert store.get("job1", "result.glb") is None and objects(s3_server, store.prefix) == []


def test_presigned_urls_name_the_public_address(s3_server):
    """Behind compose the store is `minio:9000` to the API but `localhost:9000` to clients: URLs are signed for
    the address clients ask."""
    public = s3_server.url.replace("127.0.0.1", "localhost")
    store = storage(s3_server, public_url=public)
    store.put("job1", "report.json", b"{}")
    url = store.url("job1", "report.json", 60, media_type="application/json", filename="r.json")
    assert url.startswith(f"{public}/{s3_server.bucket}/")
    assert httpx.get(url).content == b"{}"


def test_expiry_is_a_lifecycle_rule_that_keeps_the_buckets_other_rules(s3_server):
    client = s3_server.client()
    theirs = {"ID": "someone-elses", "Filter": {"Prefix": "logs/"}, "Status": "Enabled", "Expiration": {"Days": 30}}
    client.put_bucket_lifecycle_configuration(Bucket=s3_server.bucket, LifecycleConfiguration={"Rules": [theirs]})
    store = storage(s3_server, ttl_s=36 * 3600)
    store.put("job1", "target", b"t")
    assert store.sweep() == 0 and store.expiry == "lifecycle"  # the API's first sweep puts the rule
    rules = {r["ID"]: r for r in client.get_bucket_lifecycle_configuration(Bucket=s3_server.bucket)["Rules"]}
    assert rules["someone-elses"]["Expiration"] == {"Days": 30}
    assert rules[store.rule_id]["Filter"] == {"Prefix": store.prefix}
    assert rules[store.rule_id]["Expiration"] == {"Days": 2}  # 36 h, in the rule's whole days
    assert store.get("job1", "target") == b"t"  # the store expires it, not the sweep
    again = storage(s3_server, store.prefix, ttl_s=3600)  # a restarted API with another TTL updates its rule
    again.sweep()
    rules = client.get_bucket_lifecycle_configuration(Bucket=s3_server.bucket)["Rules"]
    assert sorted(r["ID"] for r in rules) == sorted(["someone-elses", store.rule_id])
    assert next(r for r in rules if r["ID"] == store.rule_id)["Expiration"] == {"Days": 1}


def test_without_a_lifecycle_rule_the_sweep_deletes_what_is_older_than_the_ttl(s3_server):
    young = storage(s3_server, ttl_s=3600, lifecycle=False)
    young.put("job1", "target", b"t")
    young.put("job2", "result.glb", b"r")
    assert young.sweep() == 0 and young.expiry == "sweep"
    assert objects(s3_server, young.prefix) == ["job1/target", "job2/result.glb"]
    time.sleep(1.1)  # the store's modification times have whole seconds
    assert storage(s3_server, young.prefix, ttl_s=1, lifecycle=False).sweep() == 2
    assert objects(s3_server, young.prefix) == []


def test_a_store_that_does_not_answer_is_storage_unavailable(s3_server, private_redis):
    down = S3Storage(s3_server.bucket, "down/", 3600, endpoint_url=f"http://127.0.0.1:{free_port()}")
    for call in (lambda: down.put("j", "a", b""), lambda: down.get("j", "a"), down.sweep):
        with pytest.raises(StorageUnavailable, match="object store failed"):
            call()
    assert down.expiry is None  # the rule is tried again at the next sweep
    # Over HTTP: a submit whose uploads cannot be stored is 503 storage_unavailable, and nothing is queued.
    env = {**s3_server.env(service_env(private_redis.url, f"s3down-{uuid.uuid4().hex[:6]}")),
           "CTP_S3_ENDPOINT_URL": down.client.meta.endpoint_url}
    api = Api(env)
    leave = park_worker(env)
    try:
        answer = submit(api)
        assert answer.status_code == 503 and answer.json()["error"]["code"] == "storage_unavailable", answer.text
        assert api.client.get("/jobs").json()["total"] == 0
    finally:
        leave()
        api.stop()


def test_a_missing_bucket_is_a_setting_error(monkeypatch):
    from service.settings import Settings

    monkeypatch.setenv("CTP_STORAGE", "s3")
    with pytest.raises(ValueError, match="CTP_S3_BUCKET"):
        Settings()
    monkeypatch.setenv("CTP_STORAGE", "redis")
    monkeypatch.setenv("CTP_S3_PRESIGN_S", "60")
    with pytest.raises(ValueError, match="CTP_STORAGE=s3"):
        Settings()


# -- workers anywhere ----------------------------------------------------------------------------------------

class Place:
    """A machine of its own, as far as one host allows: a working directory that is also the process's home,
    cache and temporary folder, so that nothing on disk is shared with the other processes."""

    def __init__(self, root: Path, name: str):
        self.dir = root / name
        self.dir.mkdir()

    def env(self, env: dict[str, str], **extra: str) -> dict[str, str]:
        own = {"HOME": self.dir, "TMPDIR": self.dir, "XDG_CACHE_HOME": self.dir / "cache", "HF_HOME": self.dir / "hf",
               "CTP_ONNX_CACHE": self.dir / "onnx", "PYTHONPATH": os.pathsep.join(filter(None, [
                   str(REPO), env.get("PYTHONPATH")]))}  # this checkout's code, wherever the process runs
        return {**env, **{k: str(v) for k, v in own.items()}, **extra}


def serve_api(place: Place, env: dict[str, str]):
    """``ctp serve --workers 0`` with REDIS_URL: the API alone, in its own process and directory."""
    port = free_port()
    log = open(place.dir / "api.log", "wb")  # noqa: SIM115 - closed by the caller
    process = subprocess.Popen(
        [sys.executable, "-m", "ctp", "serve", "--host", "127.0.0.1", "--port", str(port), "--workers", "0"],
        env=place.env(env), cwd=place.dir, stdout=log, stderr=subprocess.STDOUT)
    return process, log, f"http://127.0.0.1:{port}"


def record_of(env: dict[str, str], job_id: str):
    client = redis.Redis.from_url(env["REDIS_URL"])
    try:
        return Jobs(client, None, prefix=env["CTP_KEY_PREFIX"], ttl_s=600, job_timeout_s=60, lease_s=5).get(job_id)
    finally:
        client.close()


def test_api_and_workers_without_a_shared_disk_on_named_queues(private_redis, s3_server, tmp_path):
    """The API and the workers each in a place of their own, sharing Redis and the store only. Worker "gpu" serves
    queue gpu, worker "cpu" the default queue. The gpu worker is SIGKILLed mid-job: that job is queued again;
    the default-queue jobs succeed on the cpu worker meanwhile; a gpu job submitted while the gpu worker is down
    (within the grace) waits in its queue, and both succeed on a gpu worker started in yet another place. Results come
    as presigned URLs (links.downloads redirect); every record and every result object is there, and no upload is
    left behind."""
    prefix = f"anywhere-{uuid.uuid4().hex[:6]}"
    env = s3_server.env(service_env(private_redis.url, prefix), s3_presign_s=120)
    places = {name: Place(tmp_path, name) for name in ("api", "gpu", "cpu", "gpu-again")}
    api, api_log, url = serve_api(places["api"], env)
    gpu = Worker(places["gpu"].env(env, CTP_QUEUES="gpu"), places["gpu"].dir / "worker.log", cwd=places["gpu"].dir)
    cpu = Worker(places["cpu"].env(env), places["cpu"].dir / "worker.log", cwd=places["cpu"].dir)
    gpu_again = None
    client = Client(url)
    api_view = Api({**env, "CTP_S3_PRESIGN_S": "0"})  # another API, in the test process: it streams results
    try:
        def ready():
            try:
                answer = client.http.get("/readyz").json()
            except httpx.TransportError:  # uvicorn still starting
                return None
            return answer.get("workers") == 2 and answer

        assert wait_for(ready, 120, "the API and both workers")["queues"] == {"default": ["random:tiny"],
                                                                              "gpu": ["random:tiny"]}
        with pytest.raises(ServiceError) as refused:  # nobody serves it: refused before anything is stored
            client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on a box", options=FAST, queue="tpu")
        assert (refused.value.status, refused.value.code, refused.value.field) == (422, "queue_not_served",
                                                                                  "options.queue")
        assert "served now: default, gpu" in refused.value.message

        def send(queue: str | None = None, options=FAST) -> str:
            return client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=options,
                                 queue=queue)["id"]

        doomed = send("gpu", MID)
        wait_stepping(api_view, doomed)
        others = [send() for _ in range(2)]
        gpu.kill()  # its machine is gone
        lost = wait_status(api_view, doomed, ("queued", "failed", "succeeded", "canceled"), timeout_s=30)
        assert (lost["status"], lost["attempts"]) == ("queued", 1), lost  # run again, once
        waiting = send("gpu")  # the gpu worker was seen within the grace: accepted, queued
        assert status(api_view, waiting)["status"] == "queued"
        assert client.http.get("/readyz").json()["queues"]["gpu"] == ["random:tiny"]
        gpu_again = Worker(places["gpu-again"].env(env, CTP_QUEUES="gpu"), places["gpu-again"].dir / "worker.log",
                           cwd=places["gpu-again"].dir)

        succeeded = [*others, waiting, doomed]
        for job_id in succeeded:
            final = client.wait(job_id, timeout_s=180)
            assert final["status"] == "succeeded", final
            assert final["links"]["downloads"] == "redirect"
        # Each job ran where its queue sent it.
        ran_on = {job_id: record_of(env, job_id).worker for job_id in [doomed, *succeeded]}
        pids = {name: process.process.pid for name, process in (("gpu", gpu), ("cpu", cpu), ("gpu-again", gpu_again))}
        assert [ran_on[doomed].endswith(f".{pids['gpu-again']}"), ran_on[waiting].endswith(f".{pids['gpu-again']}")
                ] == [True, True]
        assert all(ran_on[job_id].endswith(f".{pids['cpu']}") for job_id in others), ran_on

        # Results: 307 to the store (report.json: streamed, redacted); the client follows without its key; the bytes
        # are the stored object's.
        store = s3_server.client()
        for job_id in succeeded:
            for name in OUTPUTS:
                answer = client.http.get(f"/jobs/{job_id}/{name}")
                if name == "report.json":
                    assert answer.status_code == 200
                else:
                    assert answer.status_code == 307 and answer.headers["location"].startswith(s3_server.url)
                stored = store.get_object(Bucket=s3_server.bucket, Key=f"{prefix}/{job_id}/{name}")["Body"].read()
                assert client.download(job_id, name) == stored and stored
        # An API that streams serves the same jobs itself: what the links promised, while it is still configured.
        assert api_view.client.get(f"/jobs/{others[0]}/report.json").status_code == 200
        # Nothing lost, nothing left: every job's record; each succeeded job's results; no upload of any.
        assert all(record_of(env, job_id) is not None for job_id in succeeded)
        stored = {job_id: [*OUTPUTS, *(alternative_blob(k) for k in range(1, len(record_of(env, job_id).alternatives)))]
                  for job_id in succeeded}  # and the other alternatives' GLBs
        assert objects(s3_server, f"{prefix}/") == sorted(f"{job_id}/{name}" for job_id in succeeded
                                                          for name in stored[job_id])
    finally:
        client.close()
        api_view.stop()
        for worker in (gpu, cpu, gpu_again):
            if worker is not None:
                worker.stop()
        stop_processes([api])
        api_log.close()
