"""Bounded loading of untrusted meshes: ``ctp_core.io.load_mesh`` in a small pool of separate processes.

A pathological upload (a scene graph built to be slow, a texture built to be huge) must cost at most a
few seconds and a bounded amount of memory, and never the process that received it. So loading runs
in child processes started fresh (``python -m ctp_core.io.loader``: spawned, never forked from a threaded
server) that import only what loading needs (numpy, trimesh, PIL; not torch), under two limits:

- **memory**: ``RLIMIT_AS`` (address space) of each child, ``memory_bytes`` (default 3 GiB; a child
  idles at about 0.4 GiB). Over it, allocation fails and the load ends ``mesh_too_complex``.
- **wall time**: ``timeout_s`` per load (default 20 s); past it the child is killed (SIGKILL) and
  replaced, and the load ends ``mesh_too_complex``. ``RLIMIT_CPU`` backs it up inside the child, so a
  child whose parent vanished mid-load cannot spin on.

A child that dies for any other reason is replaced the same way. ``close()`` kills the children, so a
caller waiting on one returns at once (``loader_unavailable``) and shutdown never waits on a load. The children
run in a process group of their own: a terminal's Ctrl-C (SIGINT to the foreground group) or a SIGTERM to the
owner's group reaches the owner, which decides what its loads in flight mean, never a child mid-start or mid-load.
The service, the worker and the CLI all load uploads through a ``MeshLoader``.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import queue
import resource
import select
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from ctp_core.errors import CtpError, MeshError
from ctp_core.io import MeshLimits, label_of

_HEADER = struct.Struct("<Q")
_READY = "ready"
_ROOT = str(Path(__file__).resolve().parents[1])  # the children import this same tree
# one thread each: the child's address space stays small and two loads do not fight over two cores
_THREAD_ENV = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


class LoaderUnavailable(CtpError):
    """No loading process could serve the request (shutting down, or every one busy for too long)."""

    code = "loader_unavailable"


class MeshLoader:
    """``load``/``check`` meshes in up to ``processes`` children, each load under the limits above.

    Children start on first use and are reused; thread-safe (a caller waits for a free child up to the
    longest another caller can hold one, ``timeout_s + start_timeout_s``, then gets ``loader_unavailable``).
    """

    def __init__(self, processes: int = 2, *, timeout_s: float = 20.0, memory_bytes: int = 3 * 2**30,
                 start_timeout_s: float = 60.0):
        self.timeout_s, self.memory_bytes, self.start_timeout_s = timeout_s, memory_bytes, start_timeout_s
        self._idle: queue.LifoQueue[_Child | None] = queue.LifoQueue()
        for _ in range(processes):
            self._idle.put(None)  # a slot whose child is not started yet
        self._live: set[_Child] = set()
        self._lock = threading.Lock()
        self._closed = False

    def load(self, data: str | Path | bytes, *, filename: str | None = None,
             limits: MeshLimits | None = None, name: str | None = None):
        """As ``ctp_core.io.load_mesh``, in a child; returns the ``trimesh.Trimesh``."""
        return self._call(data, filename, limits or MeshLimits(), name, True)

    def check(self, data: bytes, filename: str, limits: MeshLimits) -> int:
        """Load and validate without sending the mesh back (the service's check); returns its face count."""
        return self._call(data, filename, limits, filename, False)

    def close(self) -> None:
        """Kill every child; loads in flight end with ``loader_unavailable``."""
        with self._lock:
            self._closed = True
            live, self._live = self._live, set()
        for child in live:
            child.kill()

    def __enter__(self) -> MeshLoader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _call(self, data, filename, limits: MeshLimits, name, want_mesh: bool):
        label = label_of(data, filename, name)
        # the loading processes run in the package root, so a relative path is made absolute here
        payload = str(Path(data).absolute()) if isinstance(data, str | Path) else data
        wait = self.timeout_s + self.start_timeout_s  # the longest a holder can keep its process
        try:
            child = self._idle.get(timeout=wait)
        except queue.Empty:
            raise LoaderUnavailable(f"{label}: every loading process stayed busy for {wait:.0f} s; "
                                    "try again") from None
        reply = None
        try:
            for attempt in range(2):
                if child is None or not child.alive():
                    child = self._spawn()
                try:
                    reply = child.request((payload, filename, limits, name, want_mesh, self.timeout_s), self.timeout_s)
                    break
                except _Died as exc:
                    if not exc.unsent or attempt:
                        raise
                    self._forget(child)  # it died idle, before this file reached it: not the file's fault
                    child = None
            if reply[:2] == ("error", "mesh_too_complex"):  # out of memory: that child exits, start afresh
                self._forget(child)
                child = None
        except _Died as exc:
            if child is not None:
                self._forget(child)
                child = None
            if self._closed:
                raise LoaderUnavailable(f"{label}: the service is shutting down") from None
            if exc.timed_out:
                raise MeshError(f"{label}: loading took over {self.timeout_s:.0f} s; the file is too complex",
                                code="mesh_too_complex") from None
            raise MeshError(f"{label}: loading exceeded its memory limit ({self.memory_bytes / 2**30:.1f} GiB) "
                            f"or crashed ({exc}); the file is too complex", code="mesh_too_complex") from None
        finally:
            if reply is None and child is not None:  # interrupted mid-request (rq timeout, ^C): start afresh
                self._forget(child)
                child = None
            self._idle.put(child)
        if reply[0] == "error":
            raise MeshError(reply[2], code=reply[1])
        return reply[1]

    def _spawn(self) -> _Child:
        with self._lock:
            if self._closed:
                raise _Died("closed")
        try:
            child = _Child(self.memory_bytes, self.start_timeout_s)
        except (OSError, _Died) as exc:
            raise LoaderUnavailable(f"could not start a loading process: {exc}") from None
        with self._lock:
            self._live.add(child)
            if self._closed:
                child.kill()
        return child

    def _forget(self, child: _Child) -> None:
        child.kill()
        with self._lock:
            self._live.discard(child)


class _Died(Exception):
    """The child is gone: killed at the wall-time limit, crashed, or dead before the request was sent."""

    def __init__(self, what: str, timed_out: bool = False, unsent: bool = False):
        super().__init__(what)
        self.timed_out, self.unsent = timed_out, unsent


class _Child:
    """One loading process and its two pipes (requests in on stdin, replies out on stdout)."""

    def __init__(self, memory_bytes: int, start_timeout_s: float):
        env = {**os.environ, **_THREAD_ENV, "PYTHONPATH": os.pathsep.join(
            [_ROOT, *filter(None, [os.environ.get("PYTHONPATH")])])}
        self.process = subprocess.Popen([sys.executable, "-m", "ctp_core.io.loader", str(memory_bytes)],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, cwd=_ROOT,
                                        process_group=0)
        try:
            if self._read(time.monotonic() + start_timeout_s, start=True) != (_READY,):
                raise _Died("the loading process did not start")
        except BaseException:
            self.kill()
            raise

    def alive(self) -> bool:
        return self.process.poll() is None

    def request(self, message: tuple, timeout_s: float) -> tuple:
        body = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        try:
            self.process.stdin.write(_HEADER.pack(len(body)) + body)
            self.process.stdin.flush()
        except (BrokenPipeError, OSError) as exc:
            self.kill()
            raise _Died(f"write failed: {exc}", unsent=True) from None
        return self._read(time.monotonic() + timeout_s)

    def _read(self, deadline: float, start: bool = False) -> tuple:
        fd = self.process.stdout.fileno()
        chunks: list[bytes] = []
        need, header = _HEADER.size, True
        while need:
            wait = deadline - time.monotonic()
            ready = select.select([fd], [], [], max(wait, 0))[0] if wait > 0 else []
            if not ready:
                self.kill()
                raise _Died("timed out", timed_out=not start)
            chunk = os.read(fd, min(need, 1 << 20))
            if not chunk:
                code = self.kill()
                raise _Died(f"exit status {code}")
            chunks.append(chunk)
            need -= len(chunk)
            if not need and header:
                need, header, chunks = _HEADER.unpack(b"".join(chunks))[0], False, []
        return pickle.loads(b"".join(chunks))

    def kill(self) -> int | None:
        with contextlib.suppress(OSError):
            self.process.kill()
        with contextlib.suppress(OSError):
            self.process.stdin.close()
        code = self.process.wait()
        with contextlib.suppress(OSError):
            self.process.stdout.close()
        return code


def _serve(memory_bytes: int) -> None:
    """The child: set the limits, import the loader, then answer requests until stdin closes."""
    replies = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # anything a library prints goes to stderr, never into the replies
    requests = os.fdopen(0, "rb")
    # Started mid-job by a worker, this process inherits the job's data ceiling (worker.memory.job_memory),
    # sized to the worker's memory, not ours: our own limit is the address space below.
    _, data_hard = resource.getrlimit(resource.RLIMIT_DATA)
    resource.setrlimit(resource.RLIMIT_DATA, (data_hard, data_hard))
    resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
    from ctp_core import io

    def send(message: Any) -> None:
        body = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        replies.write(_HEADER.pack(len(body)) + body)
        replies.flush()

    send((_READY,))
    while header := requests.read(_HEADER.size):
        data, filename, limits, name, want_mesh, timeout_s = pickle.loads(requests.read(_HEADER.unpack(header)[0]))
        used = resource.getrusage(resource.RUSAGE_SELF)
        cpu = int(used.ru_utime + used.ru_stime + timeout_s) + 5  # the parent's wall limit comes first
        resource.setrlimit(resource.RLIMIT_CPU, (cpu, resource.RLIM_INFINITY))
        try:
            mesh = io.load_mesh(data, filename=filename, limits=limits, name=name)
            send(("ok", mesh if want_mesh else len(mesh.faces)))
        except MeshError as exc:
            send(("error", exc.code, exc.message))
        except MemoryError:
            send(("error", "mesh_too_complex", f"{name or filename}: loading exceeded its memory limit "
                  f"({memory_bytes / 2**30:.1f} GiB); the file is too complex"))
            return  # a fresh process takes this one's place


if __name__ == "__main__":
    _serve(int(sys.argv[1]))
