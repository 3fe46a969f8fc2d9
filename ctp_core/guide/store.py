"""Guidance models in the local Hugging Face cache, the one the ``hf:`` loader reads: what is there (``cached``),
bringing one in (``pull``) and removing it (``remove``); ``ctp models`` is the command line over them.

``pull`` speaks the Hub's HTTP API (``HF_ENDPOINT``, default huggingface.co; ``HF_TOKEN`` when set): the
repository's file list with checksums (``/api/models/REPO/revision/REV?blobs=true``), then each file a
checkpoint needs (config, tokenizer and processor files, one weights format) from ``/REPO/resolve/SHA/FILE``.
Each file is written as the hub client writes it (``blobs/ETAG`` behind a relative link in
``snapshots/SHA/``, ``refs/REV``), so ``transformers`` and ``checkpoints.missing`` find it offline; a broken
download resumes where it stopped (``blobs/ETAG.incomplete``, an HTTP range request) and a file is kept only
when its checksum is the Hub's (sha256 of an LFS file, git's blob id of the others). No torch import.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ctp_core.config import DEFAULT_MODEL
from ctp_core.errors import ConfigError, ModelError
from ctp_core.guide.checkpoints import WEIGHT_FILES, env_true, missing

HUB = "https://huggingface.co"
CHUNK = 1 << 20
TIMEOUT_S = 30.0
_REPO = re.compile(r"[A-Za-z0-9][\w.-]*/[\w.-]+")
_SHA256 = re.compile(r"[0-9a-f]{64}")
ProgressCallback = Callable[[int, int], None]  # (bytes done, bytes in all)
# The weights formats, preferred first: (the file, the pattern of its shards when it is an index).
FORMATS = (("model.safetensors", None), ("model.safetensors.index.json", r"model-\d+-of-\d+\.safetensors"),
           ("pytorch_model.bin", None), ("pytorch_model.bin.index.json", r"pytorch_model-\d+-of-\d+\.bin"))


@dataclass(frozen=True)
class CachedModel:
    """One model repository in the cache: its spec, bytes on disk, the weights file's sha256, whether it loads
    offline (config and weights present), whether it is the default model (``auto``'s)."""

    spec: str
    size: int
    sha256: str | None
    ready: bool
    default: bool


def repo_id(name: str) -> str:
    """``hf:ORG/NAME`` or ``ORG/NAME`` -> ``ORG/NAME``; ``ConfigError`` for anything else (a local folder, another
    backend: nothing to pull)."""
    repo = name.removeprefix("hf:")
    if not _REPO.fullmatch(repo):
        raise ConfigError(f"{name!r} is not a Hugging Face model id (ORG/NAME, e.g. "
                          f"{DEFAULT_MODEL.removeprefix('hf:')})", field="name")
    return repo


def cache_root(cache_dir: str | Path | None = None) -> Path:
    """The Hugging Face hub cache (``HF_HUB_CACHE``, ``HF_HOME``/hub, ~/.cache/huggingface/hub)."""
    from huggingface_hub import constants

    return Path(cache_dir or constants.HF_HUB_CACHE)


def _folder(repo: str, cache_dir: str | Path | None) -> Path:
    return cache_root(cache_dir) / f"models--{repo.replace('/', '--')}"


def cached(cache_dir: str | Path | None = None) -> list[CachedModel]:
    """Every model repository in the cache, by name."""
    root = cache_root(cache_dir)
    folders = sorted(root.glob("models--*")) if root.is_dir() else []
    return [_describe(folder.name.removeprefix("models--").replace("--", "/"), cache_dir) for folder in folders]


def _describe(repo: str, cache_dir: str | Path | None) -> CachedModel:
    folder = _folder(repo, cache_dir)
    size = sum(f.stat().st_size for f in (folder / "blobs").glob("*") if f.is_file())
    ref = folder / "refs" / "main"
    snapshot = folder / "snapshots" / ref.read_text().strip() if ref.is_file() else None
    weights = next((snapshot / f for f in WEIGHT_FILES if snapshot and (snapshot / f).is_file()), None)
    spec = f"hf:{repo}"
    return CachedModel(spec, size, weights and _sha256_of(weights), missing(spec, cache_dir=str(cache_root(cache_dir)),
                       offline=True) is None, spec == DEFAULT_MODEL)


def _sha256_of(path: Path) -> str:
    """A cached file's sha256: its blob's name for an LFS file (the hub names blobs by it), else computed."""
    blob = path.resolve().name
    return blob if _SHA256.fullmatch(blob) else _hash(path, hashlib.sha256())


def _hash(path: Path, digest, prefix: bytes = b"") -> str:
    digest.update(prefix)
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(CHUNK), b""):
            digest.update(chunk)
    return digest.hexdigest()


def remove(name: str, cache_dir: str | Path | None = None) -> int:
    """Delete a model from the cache; returns the bytes freed. ``ConfigError`` when it is not there."""
    repo = repo_id(name)
    folder = _folder(repo, cache_dir)
    if not folder.is_dir():
        raise ConfigError(f"{repo} is not in the cache ({cache_root(cache_dir)})", code="model_not_cached",
                          field="name")
    size = _describe(repo, cache_dir).size
    shutil.rmtree(folder)
    return size


@dataclass(frozen=True)
class _File:
    name: str
    size: int
    etag: str  # the blob's name: sha256 of an LFS file, git's blob id of the others
    lfs: bool

    def verified(self, path: Path) -> bool:
        if path.stat().st_size != self.size:
            return False
        if self.lfs:
            return _hash(path, hashlib.sha256()) == self.etag
        return _hash(path, hashlib.sha1(), f"blob {self.size}\0".encode()) == self.etag  # noqa: S324 - git's id


def pull(name: str, *, cache_dir: str | Path | None = None, endpoint: str | None = None, revision: str = "main",
         on_progress: ProgressCallback | None = None) -> CachedModel:
    """Download what ``hf:NAME`` needs to load offline into the cache (module docstring); files already there
    and verified are kept. ``ModelError`` when the Hub cannot be reached or refuses, or a checksum differs."""
    import httpx

    repo = repo_id(name)
    endpoint = (endpoint or os.environ.get("HF_ENDPOINT") or HUB).rstrip("/")
    if env_true("HF_HUB_OFFLINE"):
        raise ModelError(f"cannot pull {repo}: HF_HUB_OFFLINE is set", code="model_unreachable", field="name")
    token = os.environ.get("HF_TOKEN")
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    with httpx.Client(headers=headers, timeout=TIMEOUT_S, follow_redirects=True) as client:
        info = _get(client, f"{endpoint}/api/models/{repo}/revision/{revision}", repo, endpoint, params={"blobs": True})
        commit, files = info["sha"], _needed(repo, info.get("siblings") or [])
        folder = _folder(repo, cache_dir)
        total = sum(f.size for f in files)
        done = 0
        for file in files:
            done = _fetch(client, f"{endpoint}/{repo}/resolve/{commit}/{file.name}", folder, commit, file, repo,
                          endpoint, done, total, on_progress)
    (folder / "refs").mkdir(parents=True, exist_ok=True)
    (folder / "refs" / revision).write_text(commit)
    return _describe(repo, cache_dir)


def _needed(repo: str, siblings: list[dict[str, Any]]) -> list[_File]:
    """What a checkpoint needs to load: its top-level JSON, text and tokenizer-model files, and one weights
    format (safetensors first; the shards of a sharded one)."""
    names = {s["rfilename"]: s for s in siblings}
    for main, shard in FORMATS:
        if main in names:
            chosen = {main, *(n for n in names if shard and re.fullmatch(shard, n))}
            break
    else:
        raise ModelError(f"{repo} has none of {', '.join(WEIGHT_FILES)}: not a transformers checkpoint", field="name")
    chosen |= {n for n in names if "/" not in n and n.endswith((".json", ".txt", ".model"))
               and not n.endswith(".index.json")}
    files = []
    for n in sorted(chosen):
        lfs = names[n].get("lfs")
        etag = lfs["sha256"] if lfs else names[n].get("blobId")
        if not etag or names[n].get("size") is None:
            raise ModelError(f"{repo}: the Hub gave no checksum for {n}", code="model_unreachable", field="name")
        files.append(_File(n, int(names[n]["size"]), etag, bool(lfs)))
    return files


def _fetch(client, url: str, folder: Path, commit: str, file: _File, repo: str, endpoint: str, done: int, total: int,
           on_progress: ProgressCallback | None) -> int:
    """One file into ``blobs/`` (resumed from its ``.incomplete`` part, verified) and linked from the snapshot;
    returns the bytes done so far."""
    import httpx

    blobs = folder / "blobs"
    blob, part = blobs / file.etag, blobs / f"{file.etag}.incomplete"
    if not (blob.is_file() and file.verified(blob)):
        blobs.mkdir(parents=True, exist_ok=True)
        have = part.stat().st_size if part.is_file() else 0
        have = 0 if have > file.size else have
        try:
            with client.stream("GET", url, headers={"Range": f"bytes={have}-"} if have else {}) as answer:
                if answer.status_code not in (200, 206):
                    raise ModelError(f"{endpoint} answered {answer.status_code} for {repo}/{file.name}",
                                     code="model_unreachable", field="name")
                have = have if answer.status_code == 206 else 0  # 200: the server sends it whole
                with open(part, "ab" if have else "wb") as out:
                    for chunk in answer.iter_bytes():  # as it arrives: a broken answer keeps what came
                        out.write(chunk)
                        have += len(chunk)
                        if on_progress is not None:
                            on_progress(done + have, total)
        except httpx.HTTPError as exc:
            raise ModelError(f"cannot download {repo}/{file.name} from {endpoint}: {exc or type(exc).__name__} "
                             "(run it again to resume)", code="model_unreachable", field="name") from None
        if not file.verified(part):
            part.unlink()
            raise ModelError(f"{repo}/{file.name} from {endpoint} does not match the Hub's checksum; it was deleted",
                             code="model_corrupt", field="name")
        part.replace(blob)
    link = folder / "snapshots" / commit / file.name
    link.parent.mkdir(parents=True, exist_ok=True)
    link.unlink(missing_ok=True)
    link.symlink_to(os.path.relpath(blob, link.parent))
    if on_progress is not None:
        on_progress(done + file.size, total)
    return done + file.size


def _get(client, url: str, repo: str, endpoint: str, **kwargs) -> dict[str, Any]:
    import httpx

    try:
        answer = client.get(url, **kwargs)
    except httpx.HTTPError as exc:
        raise ModelError(f"cannot reach {endpoint} to pull {repo}: {exc or type(exc).__name__}",
                         code="model_unreachable", field="name") from None
    if answer.status_code in (401, 403, 404):
        raise ModelError(f"{endpoint} has no model {repo} this machine may read ({answer.status_code}; a gated or "
                         "private one needs HF_TOKEN)", code="model_not_found", field="name")
    if answer.status_code != 200:
        raise ModelError(f"{endpoint} answered {answer.status_code} for {repo}", code="model_unreachable",
                         field="name")
    return answer.json()
