"""Where uploads and results live between the API and the workers.

Every back end expires what it holds after the job TTL, so nothing has to be cleaned up by hand:
``RedisStorage`` (the default) needs nothing but the Redis URL, so a worker on another machine can run
a job, but keeps every blob in Redis memory; ``DirStorage`` keeps them on disk and needs a directory that
the API and all workers share (a volume); ``S3Storage`` keeps them in an S3-compatible object store (AWS
S3, MinIO, ...), which any number of machines reach with no shared disk, and can hand clients short-lived
download URLs so that results need not pass through the API.
"""

from __future__ import annotations

import logging
import math
import os
import re
import shutil
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

import boto3
from botocore.config import Config
from botocore.exceptions import BotoCoreError, ClientError
from redis import Redis

if TYPE_CHECKING:
    from service.settings import Settings

log = logging.getLogger("ctp.service")

_NAME = re.compile(r"^[A-Za-z0-9_.-]+$")
DAY_S = 24 * 3600


class StorageUnavailable(Exception):
    """The store did not answer, or refused (credentials, bucket): the API answers 503 storage_unavailable."""


class Storage(Protocol):
    def put(self, job_id: str, name: str, data: bytes) -> None: ...
    def get(self, job_id: str, name: str) -> bytes | None: ...
    def delete(self, job_id: str, names: list[str]) -> None: ...
    def sweep(self) -> int: ...

    def url(self, job_id: str, name: str, expires_s: int, *, media_type: str, filename: str) -> str | None:
        """A URL that serves the blob directly for ``expires_s`` seconds, as ``media_type`` and as an attachment
        named ``filename``; None when there is none to give (the blob is gone, or the back end has no such
        URLs): the API streams the blob then."""
        ...


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

    def url(self, job_id: str, name: str, expires_s: int, *, media_type: str, filename: str) -> str | None:
        return None


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

    def url(self, job_id: str, name: str, expires_s: int, *, media_type: str, filename: str) -> str | None:
        return None


class S3Storage:
    """Blobs as objects ``{prefix}{job}/{name}`` of one bucket of an S3-compatible store (boto3).

    Credentials come from the standard AWS chain (environment, shared files, instance or task role), so a
    worker needs object read, write and delete and nothing else. Expiry: the first ``sweep`` (the API's reaper calls it
    at start; workers never do) puts a lifecycle rule on the bucket that expires this prefix after the job
    TTL, rounded up to whole days (the rule's unit; the store removes expired objects within about a day
    after that, and the job records that name them are gone at the TTL anyway). A store or a credential that
    refuses the rule, or ``lifecycle=False``, leaves it to the sweep, which lists the prefix and deletes the
    objects older than the TTL.
    """

    def __init__(self, bucket: str, prefix: str, ttl_s: int, *, endpoint_url: str | None = None,
                 public_url: str | None = None, lifecycle: bool = True):
        self.bucket, self.prefix, self.ttl_s = bucket, prefix, ttl_s
        # A non-AWS endpoint (MinIO, moto) is addressed by path: bucket names are not resolvable host names there.
        config = Config(s3={"addressing_style": "path"} if endpoint_url else {}, signature_version="s3v4",
                        retries={"mode": "standard"}, connect_timeout=5, read_timeout=60)
        session = boto3.session.Session()  # sessions are not thread-safe, the clients made from one are
        self.client = session.client("s3", endpoint_url=endpoint_url, config=config)
        # Presigned URLs are signed for the host clients will ask (a compose service's name is not theirs).
        self.signer = (session.client("s3", endpoint_url=public_url, config=config)
                       if public_url and public_url != endpoint_url else self.client)
        self.expiry: Literal["lifecycle", "sweep"] | None = None if lifecycle else "sweep"  # set by the first sweep

    def _key(self, job_id: str, name: str) -> str:
        _check(job_id, name)
        return f"{self.prefix}{job_id}/{name}"

    def put(self, job_id: str, name: str, data: bytes) -> None:
        with _unavailable("store"):
            self.client.put_object(Bucket=self.bucket, Key=self._key(job_id, name), Body=data)

    def get(self, job_id: str, name: str) -> bytes | None:
        with _unavailable("read"):
            try:
                return self.client.get_object(Bucket=self.bucket, Key=self._key(job_id, name))["Body"].read()
            except ClientError as exc:
                if _missing(exc):
                    return None
                raise

    def delete(self, job_id: str, names: list[str]) -> None:
        if names:
            self._delete([self._key(job_id, n) for n in names])

    def url(self, job_id: str, name: str, expires_s: int, *, media_type: str, filename: str) -> str | None:
        key = self._key(job_id, name)
        with _unavailable("read"):
            try:
                self.client.head_object(Bucket=self.bucket, Key=key)  # an expired result stays the API's 404
            except ClientError as exc:
                if _missing(exc):
                    return None
                raise
            return self.signer.generate_presigned_url("get_object", ExpiresIn=expires_s, Params={
                "Bucket": self.bucket, "Key": key, "ResponseContentType": media_type,
                "ResponseContentDisposition": f'attachment; filename="{filename}"'})

    def sweep(self) -> int:
        if self.expiry is None:
            self.expiry = self._put_lifecycle_rule()
        if self.expiry == "lifecycle":
            return 0
        cutoff = time.time() - self.ttl_s
        with _unavailable("list"):
            pages = self.client.get_paginator("list_objects_v2").paginate(Bucket=self.bucket, Prefix=self.prefix)
            old = [o["Key"] for page in pages for o in page.get("Contents", [])
                   if o["LastModified"].timestamp() < cutoff]
        self._delete(old)
        return len(old)

    @property
    def rule_id(self) -> str:
        return f"ctp-expire-{self.prefix}"[:255]

    def _put_lifecycle_rule(self) -> Literal["lifecycle", "sweep"]:
        """Install (or update) this prefix's expiry rule, keeping the bucket's other rules; returns how objects
        expire from now on: "lifecycle", or "sweep" when the store or the credentials refuse the rule."""
        rule = {"ID": self.rule_id, "Filter": {"Prefix": self.prefix}, "Status": "Enabled",
                "Expiration": {"Days": max(1, math.ceil(self.ttl_s / DAY_S))}}
        with _unavailable("configure"):
            try:
                try:
                    rules = self.client.get_bucket_lifecycle_configuration(Bucket=self.bucket)["Rules"]
                except ClientError as exc:
                    if exc.response.get("Error", {}).get("Code") != "NoSuchLifecycleConfiguration":
                        raise
                    rules = []
                rules = [r for r in rules if r.get("ID") != self.rule_id] + [rule]
                self.client.put_bucket_lifecycle_configuration(Bucket=self.bucket,
                                                               LifecycleConfiguration={"Rules": rules})
            except ClientError as exc:  # not implemented by the store, or not allowed to this key
                log.warning("s3: no lifecycle rule on bucket %s (%s); expired objects are deleted by the sweep",
                            self.bucket, exc.response.get("Error", {}).get("Code", exc))
                return "sweep"
        log.info("s3: objects under %s/%s expire after %d day(s) (lifecycle rule %s)", self.bucket, self.prefix,
                 rule["Expiration"]["Days"], self.rule_id)
        return "lifecycle"

    def _delete(self, keys: list[str]) -> None:
        with _unavailable("delete"):
            for start in range(0, len(keys), 1000):  # the most one request may name
                self.client.delete_objects(Bucket=self.bucket, Delete={
                    "Objects": [{"Key": k} for k in keys[start:start + 1000]], "Quiet": True})


def _missing(exc: ClientError) -> bool:
    return exc.response.get("Error", {}).get("Code") in ("NoSuchKey", "404", "NotFound")


@contextmanager
def _unavailable(action: str) -> Iterator[None]:
    """Turn the client's failures (no answer, refused credentials, missing bucket) into StorageUnavailable."""
    try:
        yield
    except (BotoCoreError, ClientError) as exc:
        raise StorageUnavailable(f"the object store failed to {action}: {exc}") from exc


def open_storage(redis: Redis, settings: Settings) -> Storage:
    """The configured back end (``CTP_STORAGE``)."""
    backend = settings.storage_backend
    if backend == "s3":
        return S3Storage(settings.s3_bucket, settings.s3_prefix, settings.job_ttl_s,
                         endpoint_url=settings.s3_endpoint_url, public_url=settings.s3_public_url,
                         lifecycle=settings.s3_lifecycle)
    if backend == "dir":
        return DirStorage(settings.storage_dir, settings.job_ttl_s)
    return RedisStorage(redis, settings.key_prefix, settings.job_ttl_s)
