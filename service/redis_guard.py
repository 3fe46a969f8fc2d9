"""The keeper of the embedded redis-server: ``python -m service.redis_guard --lifeline FD --lock FD --port PORT --
redis-server ARGS...`` (started by ``service.embedded``).

redis-server is a program of its own that cannot watch a lifeline (``service.lifeline``); this small process watches
it for it, and stops the server in the order a clean stop of ``ctp serve`` keeps, Redis last:

- on SIGTERM, SIGINT or SIGHUP (``EmbeddedRedis.stop``, once the workers are stopped): at once;
- once the lifeline ends (the process that started it died, SIGKILL included): when no client is left, that is once
  the orphaned workers have handed their running jobs back to it and left (``ctp worker --lifeline``), and at most
  ``DRAIN_S`` later.

Stopping is SIGTERM, which redis-server takes as ``SHUTDOWN``: the append-only file is flushed. The server also gets
SIGTERM from the kernel if this keeper is killed (a parent-death signal: this process is single-threaded when it
starts the server, so the signal is tied to the keeper's life). The data folder's lock (``--lock``, a descriptor of a
file under ``flock``) is passed on to the server, so the lock is held as long as the server lives, whoever started
it (``EmbeddedRedis``). The keeper exits when the server does, with its status (128 + the signal that ended it).
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import os
import signal
import subprocess
import threading
import time
from collections.abc import Callable

from service import lifeline

DRAIN_S = 15.0  # > the 10 s an orphaned worker gets to hand its job back (``ctp.cmd_serve.STOP_GRACE_S``)
POLL_S = 0.1
PR_SET_PDEATHSIG = 1


def _dies_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` that gives the child SIGTERM when this process dies (Linux), and ends the child at once if
    this process died before that took hold; None where ``prctl`` is missing."""
    prctl = getattr(ctypes.CDLL(None, use_errno=True), "prctl", None)
    if prctl is None:
        return None
    parent = os.getpid()

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != parent:
            os._exit(1)

    return preexec


def _clients(port: int) -> int:
    """Clients connected to the server besides this one; 0 when it does not answer (nothing to wait for)."""
    import redis

    # retry None: no retries (redis-py 8 retries by default); its stubs ask for a Retry
    client = redis.Redis(port=port, socket_connect_timeout=1, socket_timeout=1, retry=None)  # type: ignore[arg-type]
    try:
        return int(client.info("clients")["connected_clients"]) - 1
    except redis.RedisError:
        return 0
    finally:
        client.close()


def _drain(port: int, server: subprocess.Popen) -> None:
    """Wait, at most ``DRAIN_S``, for the server's clients to leave (or for the server to end)."""
    deadline = time.monotonic() + DRAIN_S
    while time.monotonic() < deadline and server.poll() is None and _clients(port) > 0:
        time.sleep(POLL_S)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m service.redis_guard")
    parser.add_argument("--lifeline", type=int, required=True)
    parser.add_argument("--lock", type=int, required=True)
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    # started before any thread of this process: the preexec_fn is safe, the parent-death signal tied to the keeper
    server = subprocess.Popen(command, pass_fds=(args.lock,), preexec_fn=_dies_with_parent(),
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    stopping = threading.Event()

    def stop(*_: object) -> None:
        stopping.set()
        with contextlib.suppress(OSError):
            server.send_signal(signal.SIGTERM)

    for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(signum, stop)
    orphaned = threading.Event()
    lifeline.watch(args.lifeline, orphaned.set)
    while server.poll() is None and not orphaned.wait(POLL_S):
        pass
    if server.poll() is None and not stopping.is_set():  # the parent is gone: its workers leave first
        _drain(args.port, server)
        stop()
    code = server.wait()
    return code if code >= 0 else 128 - code


if __name__ == "__main__":
    raise SystemExit(main())
