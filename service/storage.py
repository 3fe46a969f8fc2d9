"""Where uploads and results live between the API and the workers.

Both back ends expire what they hold after the job TTL, so nothing has to be cleaned up by hand:
``RedisStorage`` (the default) needs nothing but the Redis URL, so a worker on another machine can run
a job; ``DirStorage`` keeps large files out of Redis memory and needs a directory that the API and all
workers share (a volume).
"""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path
from typing import Protocol

from redis import Redis

_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")


class Storage(Protocol):
    def put(self, job_id: str, name: str, data: bytes) -> None: ...
    def get(self, job_id: str, name: str) -> bytes | None: ...
    def delete(self, job_id: str, names: list[str]) -> None: ...
    def sweep(self) -> int: ...


def _check(job_id: str, name: str) -> None:
    # Names come from our own code, but they become Redis keys and paths: refuse anything odd.
    if not (_NAME.match(job_id) and _NAME.match(name)) or ".." in (job_id + name):
        raise ValueError(f"bad storage name {job_id!r}/{name!r}")


class RedisStorage:
    """Blobs as Redis strings ``{prefix}:blob:{job}:{name}`` with the job TTL."""

    def __init__(self, redis: Redis, prefix: str, ttl_s: int):
        self.redis, self.prefix, self.ttl_s = redis, prefix, ttl_s

    def _key(self, job_id: str, name: str) -> str:
        _check(job_id, name)
        return f"{self.prefix}:blob:{job_id}:{name}"

    def put(self, job_id: str, name: str, data: bytes) -> None:
        self.redis.set(self._key(job_id, name), data, ex=self.ttl_s)

    def get(self, job_id: str, name: str) -> bytes | None:
        return self.redis.get(self._key(job_id, name))

    def delete(self, job_id: str, names: list[str]) -> None:
        if names:
            self.redis.delete(*(self._key(job_id, n) for n in names))

    def sweep(self) -> int:
        return 0  # Redis expires the keys itself


class DirStorage:
    """Blobs as files ``{root}/{job}/{name}``; ``sweep`` removes job folders older than the TTL."""

    def __init__(self, root: Path, ttl_s: int):
        self.root, self.ttl_s = Path(root), ttl_s
        self.root.mkdir(parents=True, exist_ok=True)

    def _path(self, job_id: str, name: str) -> Path:
        _check(job_id, name)
        return self.root / job_id / name

    def put(self, job_id: str, name: str, data: bytes) -> None:
        path = self._path(job_id, name)
        path.parent.mkdir(exist_ok=True)
        partial = path.with_name(f".{name}.{os.getpid()}.part")
        partial.write_bytes(data)
        partial.replace(path)  # readers never see half a file

    def get(self, job_id: str, name: str) -> bytes | None:
        try:
            return self._path(job_id, name).read_bytes()
        except FileNotFoundError:
            return None

    def delete(self, job_id: str, names: list[str]) -> None:
        for name in names:
            self._path(job_id, name).unlink(missing_ok=True)

    def sweep(self) -> int:
        cutoff = time.time() - self.ttl_s
        removed = 0
        for folder in self.root.iterdir():
            if folder.is_dir() and folder.stat().st_mtime < cutoff:
                shutil.rmtree(folder, ignore_errors=True)
                removed += 1
        return removed


def open_storage(redis: Redis, prefix: str, ttl_s: int, directory: Path | None) -> Storage:
    """The configured back end: a directory when one is set, else Redis."""
    return DirStorage(directory, ttl_s) if directory is not None else RedisStorage(redis, prefix, ttl_s)
