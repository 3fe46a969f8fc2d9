"""Service settings, read once from the environment (``CTP_*``, plus the conventional ``REDIS_URL`` and, for
S3 storage, the standard AWS credential chain).

The API and the workers read the same variables, so a worker on another machine needs only the same
environment (``REDIS_URL`` and the storage settings) to join; nothing else is shared but Redis and the store.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import AliasChoices, Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from ctp_core.config import AUTO, DEFAULT_MODEL, Runtime
from ctp_core.io import MeshLimits
from ctp_core.io.loader import MeshLoader
from service.webhooks import secret_bytes

MiB = 1024 * 1024
DEFAULT_QUEUE = "default"
# A named queue becomes part of Redis keys and rq queue names: short, plain.
QUEUE_NAME = r"^[a-z0-9][a-z0-9_-]{0,31}$"
QUEUE_RULE = "1 to 32 of a-z, 0-9, '_' and '-', starting with a letter or digit"


class Settings(BaseSettings):
    """Every knob of the service; list values are comma-separated in the environment."""

    model_config = SettingsConfigDict(env_prefix="CTP_", extra="ignore")

    redis_url: str | None = Field(
        None, validation_alias=AliasChoices("REDIS_URL", "CTP_REDIS_URL"),
        description="Redis shared by the API and the workers; unset: `ctp serve` starts an embedded one",
    )
    redis_dir: Path | None = Field(
        None, description="data directory of the embedded Redis; unset: $XDG_CACHE_HOME/ctp/redis",
    )
    # Before named queues, CTP_QUEUE was both the rq queue and the key prefix; it still sets the prefix.
    key_prefix: str = Field(
        "ctp", validation_alias=AliasChoices("CTP_KEY_PREFIX", "CTP_QUEUE", "key_prefix"),
        pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$",
        description="prefix of every Redis key of this deployment (records, leases, its rq queues "
        "`{prefix}:{queue}`); deployments sharing a Redis need distinct prefixes",
    )
    default_queue: str = Field(DEFAULT_QUEUE, pattern=QUEUE_NAME,
                               description="the named queue of jobs that do not ask for one (option queue)")
    queues: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="the named queues a worker takes jobs from, first listed first; "
        "unset: the default queue",
    )
    storage: Literal["redis", "dir", "s3"] | None = Field(
        None, description="where uploads and results live: redis, dir (CTP_STORAGE_DIR) or s3 (CTP_S3_*); "
        "unset: dir when CTP_STORAGE_DIR is set, else redis",
    )
    storage_dir: Path | None = Field(
        None, description="uploads and results as files under this directory (shared by API and workers) "
        "instead of in Redis",
    )
    # S3-compatible object storage (service.storage.S3Storage); credentials come from the standard AWS chain.
    s3_bucket: str | None = Field(None, description="the bucket of uploads and results (CTP_STORAGE=s3)")
    s3_prefix: str = Field("ctp/", description="key prefix of this deployment's objects in the bucket (its "
                           "expiry rule covers exactly this prefix)")
    s3_endpoint_url: str | None = Field(None, description="the store's URL for a non-AWS store (MinIO, ...); "
                                        "unset: AWS S3")
    s3_public_url: str | None = Field(None, description="the store's URL as clients reach it, for presigned "
                                      "downloads; unset: CTP_S3_ENDPOINT_URL")
    s3_presign_s: int = Field(0, ge=0, le=7 * 24 * 3600, description="0: results are streamed through the "
                              "API; more: a result download answers 307 to a presigned URL of the store that is "
                              "valid this many seconds")
    s3_lifecycle: bool = Field(True, description="expire objects with a lifecycle rule on the bucket (set by the "
                               "API at start); false, or when the store refuses the rule: the API's sweep "
                               "deletes them")
    # Limits. A request is refused before anything is queued when it breaks one of them.
    max_request_bytes: int = Field(120 * MiB, ge=1, description="whole multipart request body")
    max_upload_bytes: int = Field(50 * MiB, ge=1, description="one mesh file")
    max_image_bytes: int = Field(10 * MiB, ge=1, description="the reference image of an image-guided job")
    max_image_pixels: int = Field(4096 * 4096, ge=1, description="reference image width times height")
    max_unzipped_bytes: int = Field(200 * MiB, ge=1, description="all members of an OBJ zip, unpacked (zip bombs)")
    max_faces: int = Field(500_000, ge=1, description="faces of one mesh after loading")
    max_nodes: int = Field(10_000, ge=1, description="nodes of a glTF scene graph")
    max_depth: int = Field(128, ge=1, description="depth of a glTF scene graph")
    load_timeout_s: float = Field(20.0, gt=0, description="wall time to load one mesh (in a loading process, "
                                  "killed past it)")
    load_memory_mb: int = Field(3072, ge=512, description="address-space limit of each loading process (MiB)")
    load_processes: int = Field(2, ge=1, description="loading processes of the API (a worker has one)")
    max_active_jobs: int = Field(4, ge=1, description="queued plus running jobs per API key")
    max_stages: int = Field(8, ge=1, description="objects one POST /assemble may place (its stages)")
    max_scene_faces: int = Field(1_000_000, ge=1, description="faces of all meshes of one job together (an "
                                 "assembly's base and sources, a chained job's target scene and source)")
    job_timeout_s: int = Field(3600, ge=1, description="a running job is failed after this long")
    job_memory_mb: int = Field(4096, ge=0, description="memory one running job may use on top of the worker's own "
                               "(MiB; a soft RLIMIT_DATA per job, Linux): past it the job fails job_too_large and "
                               "the worker takes the next one; 0: no ceiling")
    job_ttl_s: int = Field(24 * 3600, ge=60, description="job records, uploads and results expire after this")
    # Engine.
    model: str = Field(AUTO, description="guidance model of jobs that do not name one; auto: the default CLIP model "
                       "where a worker has its weights, else no guide (the geometry and the prompt's relation), "
                       "chosen per job (docs/guidance.md)")
    models: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="other model specs jobs may ask for (the default is always allowed)"
    )
    device: Literal["cpu", "cuda"] = Field("cpu", description="where workers run the model and the optimiser")
    threads: int | None = Field(None, ge=1, description="torch CPU threads per worker; unset: torch's default")
    runtime: Runtime = Field("auto", description="where workers run forward-only encoding: auto, torch, onnx, "
                             "onnx-int8 (docs/guidance.md)")
    # Liveness: a worker refreshes a lease on itself and on its running job every heartbeat; a job whose
    # lease lapses (worker killed, machine gone) is queued again once by the API's reaper, then failed worker_lost.
    heartbeat_s: float = Field(2.0, gt=0, description="worker heartbeat period")
    lease_s: int = Field(15, ge=2, description="a worker or running job silent this long is considered dead")
    progress_every_s: float = Field(3.0, gt=0, description="a running job republishes progress at least this often")
    # A worker waits out a Redis outage (worker.outage): the supervisor's restarts of a redis-server that keeps dying
    # (1 + 2 + 4 + 8 + 16 s apart) or a managed Redis's failover (tens of seconds) fit; past it the outage is no
    # blip, and a worker that exits is seen (restart counts) where one that waits is not.
    redis_patience_s: float = Field(60.0, gt=0, description="how long a worker waits for Redis to answer again "
                                    "before it exits (its supervisor starts another); its running job waits with it")
    # A worker seen this recently still counts while none is live (its restart: supervisor back-off up to 30 s,
    # start-up and model load about 15 to 25 s, from its last heartbeat): jobs are accepted and wait in the queue.
    worker_grace_s: float = Field(90.0, ge=0, description="after the last worker's lease lapsed, jobs are still "
                                  "accepted (queued) and /readyz says restarting until no worker has been seen "
                                  "for this long; 0: no grace")
    # HTTP.
    api_keys: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="bearer tokens; when set every call but /healthz and /readyz needs one "
        "and each key sees only its own jobs",
    )
    cors_origins: Annotated[list[str], NoDecode] = Field(default_factory=list, description="allowed web origins")
    log_level: str = Field("INFO", description="Python logging level name")
    # Webhooks (service.webhooks): signed with one secret per deployment, delivered by the API processes.
    webhook_secret: str | None = Field(
        None, description="signing secret of webhook deliveries, `whsec_` then base64 of at least 16 bytes "
        "(Standard Webhooks); unset: submits that ask for a webhook are refused (422 webhooks_disabled)",
    )
    webhook_allow_private: bool = Field(False, description="let webhooks call loopback, private, link-local and "
                                        "other non-public addresses (tests, single-box deployments)")
    webhook_retry_s: float = Field(3600.0, gt=0, description="a start or completed event whose delivery fails is "
                                   "retried (back-off 1 s doubling to 5 min) until this long after it happened")
    webhook_timeout_s: float = Field(10.0, gt=0, description="time limit of one delivery attempt's connect, send "
                                     "and each read")

    @field_validator("models", "api_keys", "cors_origins", "queues", mode="before")
    @classmethod
    def _comma_list(cls, value):
        if isinstance(value, str):
            return [item.strip() for item in value.split(",") if item.strip()]
        return value

    @field_validator("webhook_secret")
    @classmethod
    def _webhook_secret(cls, value: str | None) -> str | None:
        if value:
            secret_bytes(value)  # ValueError: the setting is refused at start
        return value or None

    @property
    def webhook_key(self) -> bytes | None:
        """The HMAC key deliveries are signed with; None: webhooks are off."""
        return secret_bytes(self.webhook_secret) if self.webhook_secret else None

    @field_validator("queues")
    @classmethod
    def _queue_names(cls, value: list[str]) -> list[str]:
        bad = [name for name in value if not re.match(QUEUE_NAME, name)]
        if bad:
            raise ValueError(f"queue names are {QUEUE_RULE}: {', '.join(map(repr, bad))}")
        return list(dict.fromkeys(value))

    @model_validator(mode="after")
    def _storage_settings(self) -> Settings:
        if self.storage == "dir" and self.storage_dir is None:
            raise ValueError("CTP_STORAGE=dir needs CTP_STORAGE_DIR")
        if self.storage_backend == "s3" and not self.s3_bucket:
            raise ValueError("CTP_STORAGE=s3 needs CTP_S3_BUCKET")
        if self.s3_presign_s and self.storage_backend != "s3":
            raise ValueError("CTP_S3_PRESIGN_S needs CTP_STORAGE=s3 (only an object store can serve a download)")
        return self

    @property
    def storage_backend(self) -> Literal["redis", "dir", "s3"]:
        return self.storage or ("dir" if self.storage_dir is not None else "redis")

    @property
    def served_queues(self) -> list[str]:
        """The named queues a worker with these settings takes jobs from, in order."""
        return self.queues or [self.default_queue]

    @property
    def downloads(self) -> Literal["stream", "redirect"]:
        """How result downloads answer (``Links.downloads``): the bytes, or 307 to a presigned URL."""
        return "redirect" if self.s3_presign_s else "stream"

    @property
    def mesh_limits(self) -> MeshLimits:
        return MeshLimits(max_bytes=self.max_upload_bytes, max_faces=self.max_faces,
                          max_unzipped_bytes=self.max_unzipped_bytes, max_nodes=self.max_nodes,
                          max_depth=self.max_depth)

    def mesh_loader(self, processes: int | None = None) -> MeshLoader:
        """The bounded loader (``ctp_core.io.loader``) under these limits; the caller closes it."""
        return MeshLoader(processes or self.load_processes, timeout_s=self.load_timeout_s,
                          memory_bytes=self.load_memory_mb * MiB)

    @property
    def allowed_models(self) -> list[str]:
        """The default first; with auto, the default CLIP model too (the jobs that ask for guidance get it)."""
        return list(dict.fromkeys([self.model, *([DEFAULT_MODEL] if self.model == AUTO else []), *self.models]))
