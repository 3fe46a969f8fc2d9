"""``ctp serve`` and ``ctp worker`` as a user runs them: one command gives a working service (embedded
Redis + one worker), and stopping it stops everything it started."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from ctp.cli import main
from service.client import Client
from service.embedded import free_port, servers_using
from tests.conftest import REPO, service_env, wait_for
from tests.test_loader import wide_glb
from tests.test_service import BALL, BOX, FAST


def children(pid: int) -> list[int]:
    """Direct children of ``pid`` (Linux /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def descendants(pid: int) -> list[int]:
    """Every process under ``pid``: children, theirs, and so on (Linux /proc)."""
    found = children(pid)
    for child in list(found):
        found += descendants(child)
    return found


def alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs Linux /proc to find the child processes")
def _stop(serve: subprocess.Popen, started: list[int]) -> None:
    """SIGTERM to serve alone: it exits by the signal after cleaning up, and its children are gone."""
    serve.send_signal(signal.SIGTERM)
    assert serve.wait(timeout=40) == 128 + signal.SIGTERM
    wait_for(lambda: not any(alive(p) for p in started), 20, "serve's children to exit")


def _kill_left(serve: subprocess.Popen, started: list[int], log) -> None:
    """What a test left running (it failed before ``_stop``): serve and its children, killed."""
    if serve.poll() is None:
        serve.kill()
    for pid in started:
        if alive(pid):
            os.kill(pid, signal.SIGKILL)
    log.close()


def test_one_command_service_and_clean_stop(tmp_path):
    env = service_env("unused", "ctp")
    del env["REDIS_URL"]  # the point: no Redis given
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    port = free_port()
    log = open(tmp_path / "serve.log", "wb")  # noqa: SIM115 - closed below
    serve = subprocess.Popen([sys.executable, "-m", "ctp", "serve", "--port", str(port)], env=env, cwd=REPO,
                             stdout=log, stderr=subprocess.STDOUT)
    started: list[int] = []
    try:
        with Client(f"http://127.0.0.1:{port}") as client:
            def ready():
                try:
                    return client.http.get("/readyz").status_code == 200
                except httpx.TransportError:  # uvicorn still starting
                    return False

            wait_for(ready, 120, "ctp serve to be ready", interval_s=0.5)
            assert len(children(serve.pid)) == 2  # the embedded Redis's keeper and one worker
            started = descendants(serve.pid)
            assert len(servers_using(tmp_path / "cache" / "ctp" / "redis")) == 1
            assert (tmp_path / "cache" / "ctp" / "redis" / "appendonly.aof").exists()
            job = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=FAST)
            assert client.wait(job["id"], timeout_s=120)["status"] == "succeeded"
        _stop(serve, started)
    finally:
        _kill_left(serve, started, log)


def test_worker_needs_redis_url(monkeypatch, capsys):
    monkeypatch.delenv("REDIS_URL", raising=False)
    monkeypatch.delenv("CTP_REDIS_URL", raising=False)
    assert main(["worker"]) == 2
    assert "REDIS_URL" in capsys.readouterr().err


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _child(serve_pid: int, needle: str) -> int | None:
    found = [p for p in children(serve_pid) if needle in _cmdline(p) and alive(p)]
    return found[0] if found else None


def _busy(pid: int) -> bool:
    """Whether the process is using CPU now (state R)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "R"
    except OSError:
        return False


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs Linux /proc to find the child processes")
def test_embedded_service_heals_a_killed_worker_and_redis(tmp_path):
    """SIGKILL the worker: a new one comes up and takes jobs. SIGKILL redis-server: it comes back on the
    same data (append-only file) and a job queued before the kill still runs. Then SIGTERM stops the
    service promptly although an upload is still loading."""
    env = service_env("unused", "ctp", load_timeout_s=120, max_nodes=10**6)
    del env["REDIS_URL"]
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    port = free_port()
    log = open(tmp_path / "serve.log", "wb")  # noqa: SIM115 - closed below
    serve = subprocess.Popen([sys.executable, "-m", "ctp", "serve", "--port", str(port)], env=env, cwd=REPO,
                             stdout=log, stderr=subprocess.STDOUT)
    try:
        with Client(f"http://127.0.0.1:{port}") as client:
            def ready():
                try:
                    return client.http.get("/readyz").status_code == 200
                except httpx.TransportError:
                    return False

            wait_for(ready, 120, "ctp serve to be ready", interval_s=0.5)
            worker = _child(serve.pid, " worker")
            os.kill(worker, signal.SIGKILL)
            replacement = wait_for(lambda: (p := _child(serve.pid, " worker")) not in (None, worker) and p, 30,
                                   "a new worker process")
            job = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=FAST)
            assert client.wait(job["id"], timeout_s=120)["status"] == "succeeded"
            assert not alive(worker)  # reaped, not a zombie

            busy = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on a box",
                                 options={**FAST, "steps": 100000})
            queued = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=FAST)
            wait_for(lambda: client.status(busy["id"])["status"] == "running", 60, "the long job to start")
            assert client.status(queued["id"])["status"] == "queued"
            time.sleep(1.5)  # appendfsync everysec: the submission is on disk
            folder = tmp_path / "cache" / "ctp" / "redis"
            [redis_pid] = servers_using(folder)
            os.kill(redis_pid, signal.SIGKILL)
            wait_for(lambda: (p := servers_using(folder)) and p != [redis_pid], 30, "redis-server to be restarted")
            assert len(servers_using(folder)) == 1

            def answered(job_id):
                try:
                    return client.status(job_id)
                except Exception:  # noqa: BLE001 - 503 while Redis restarts
                    return None

            assert wait_for(lambda: answered(queued["id"]), 30, "the API to reach Redis again")["status"] in (
                "queued", "running")
            with contextlib.suppress(Exception):
                client.cancel(busy["id"])
            final = wait_for(lambda: (j := answered(queued["id"])) and j["status"] in ("succeeded", "failed") and j,
                             180, "the queued job to end")
            assert final["status"] == "succeeded", final
            assert replacement

            def post_slow():
                with contextlib.suppress(httpx.HTTPError):  # the service goes away under it
                    client.http.post("/align", data={"prompt": "x"}, files={
                        "target": ("box.glb", BOX), "source": ("wide.glb", wide_glb(300_000))})

            threading.Thread(target=post_slow, daemon=True).start()
            wait_for(lambda: _child(serve.pid, "ctp_core.io.loader") and _busy(_child(serve.pid, "ctp_core.io.loader")),
                     60, "the slow upload to be loading")
        stopping = time.monotonic()
        serve.send_signal(signal.SIGTERM)
        assert serve.wait(timeout=40) == 128 + signal.SIGTERM
        assert time.monotonic() - stopping < 25  # uvicorn's grace (10 s), then the loading process is killed
    finally:
        if serve.poll() is None:
            serve.kill()
        for pid in descendants(serve.pid):
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        log.close()
    text = (tmp_path / "serve.log").read_text(errors="replace")
    assert "supervisor: worker 1 restarted" in text and "supervisor: redis-server restarted" in text


def _serve(env: dict[str, str], port: int, log, *args: str, **popen) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "ctp", "serve", "--port", str(port), *args], env=env, cwd=REPO,
                            stdout=log, stderr=subprocess.STDOUT, **popen)


def _readyz(client: Client) -> dict | None:
    try:
        answer = client.http.get("/readyz")
    except httpx.TransportError:  # uvicorn still starting
        return None
    return answer.json() if answer.status_code == 200 else None


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs Linux /proc to find the child processes")
def test_ctrl_c_drains_and_loses_no_job(tmp_path):
    """Ctrl-C in a terminal (SIGINT to the whole process group) while a job runs and another waits: the worker
    hands its job back (queued, attempt not counted), Redis stops last and keeps both; a restarted service runs
    both to success. /readyz counts no worker until the new one beats; SIGTERM to serve alone stops it too."""
    env = service_env("unused", "ctp")
    del env["REDIS_URL"]
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    port = free_port()
    log = open(tmp_path / "serve.log", "wb")  # noqa: SIM115 - closed below
    serve = _serve(env, port, log, start_new_session=True)  # its own process group, as a terminal's foreground job
    started: list[int] = []
    try:
        with Client(f"http://127.0.0.1:{port}") as client:
            wait_for(lambda: (r := _readyz(client)) and r["status"] == "ready", 120, "ctp serve to be ready", 0.5)
            started = descendants(serve.pid)
            running = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on a box",
                                    options={**FAST, "steps": 40})
            waiting = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=FAST)
            wait_for(lambda: client.status(running["id"])["progress"]["step"] > 0, 90, "the job to take a step")
        os.killpg(serve.pid, signal.SIGINT)
        assert serve.wait(timeout=60) == 128 + signal.SIGINT
        wait_for(lambda: not any(alive(p) for p in started), 20, "serve's children to exit")

        serve = _serve(env, port, log)
        with Client(f"http://127.0.0.1:{port}") as client:
            first = wait_for(lambda: _readyz(client), 60, "the API to answer")
            assert (first["status"], first["workers"]) == ("restarting", 0)  # the stopped worker does not count
            back = client.status(running["id"])
            assert (back["status"], back["attempts"], back["error"]) == ("queued", 0, None), back
            assert back["progress"]["message"].startswith("handed back by its worker")
            assert client.status(waiting["id"])["status"] == "queued"
            for job in (running, waiting):
                final = client.wait(job["id"], timeout_s=240)
                assert (final["status"], final["attempts"]) == ("succeeded", 1), final
            started = descendants(serve.pid)
        _stop(serve, started)
    finally:
        _kill_left(serve, started, log)
    text = (tmp_path / "serve.log").read_text(errors="replace")
    assert "Traceback" not in text, text
