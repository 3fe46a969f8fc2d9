"""Whether a model's weights can be had on this machine, decided without loading them (no torch import).

Readiness needs this answer cheaply and in processes that never run a model: ``ctp serve`` prints one line
at start when the default model's weights are absent, and a worker publishes which of the models it may
serve it can actually load (``worker.main``), so the API refuses a job up front instead of failing it later.
``loaders.load_guide`` gives the same message when it meets the same absence.

Weights are present when an ``hf:`` spec names a ``save_pretrained`` folder, or its repository's config and
weights are in the Hugging Face cache; an ``open_clip:`` spec needs a checkpoint file as its tag. With
downloads allowed (``downloads_allowed``) a missing download is not known to fail, so it counts as present.
``random:`` specs have no weights to miss.
"""

from __future__ import annotations

import os
from pathlib import Path

# Any one of these next to config.json is a loadable transformers checkpoint.
WEIGHT_FILES = ("model.safetensors", "model.safetensors.index.json", "pytorch_model.bin",
                "pytorch_model.bin.index.json")


TRUE = ("1", "true", "yes", "on")  # how an environment switch says yes (HF_HUB_OFFLINE, CTP_ALLOW_DOWNLOAD)


def env_true(name: str) -> bool:
    """Whether the environment variable ``name`` is set to a yes (``TRUE``)."""
    return os.environ.get(name, "").strip().lower() in TRUE


def downloads_allowed() -> bool:
    """Whether weights may be fetched: ``CTP_ALLOW_DOWNLOAD`` wins, then ``HF_HUB_OFFLINE``; default no.

    A service must not stall a job on a multi-GB download it was never told to make.
    """
    for name, allow_when_true in (("CTP_ALLOW_DOWNLOAD", True), ("HF_HUB_OFFLINE", False)):
        value = os.environ.get(name, "").strip().lower()
        if value:
            return (value in TRUE) == allow_when_true
    return False


def missing(spec: str, *, cache_dir: str | None = None, offline: bool | None = None) -> str | None:
    """Why the weights of ``spec`` cannot be had here (absent and downloads off), or None when they can.

    ``offline=None`` follows the environment (``downloads_allowed``). Only weights are checked: a malformed
    spec or an unknown random architecture is the loader's to refuse.
    """
    if offline is None:
        offline = not downloads_allowed()
    backend, _, name = spec.partition(":")
    if backend == "hf" and name:
        return _missing_hf(name, cache_dir, offline)
    if backend == "open_clip" and name:
        tag = name.partition(":")[2]
        if offline and tag and not Path(tag).expanduser().is_file():
            return ("downloads are off and open_clip cannot be limited to its cache: pass a checkpoint file as "
                    "the tag (open_clip:ARCH:/path/to/weights.pt) or set CTP_ALLOW_DOWNLOAD=1")
    return None


def looks_local(name: str) -> bool:
    """An ``hf:`` name that is a folder on disk rather than a Hub repository id."""
    return name.startswith(("/", ".", "~")) or Path(name).expanduser().exists()


def absent_message(name: str, cache_dir: str | None = None) -> str:
    """The one message for an ``hf:`` repository whose weights are not cached while downloads are off."""
    return (f"weights for {name!r} are not in the Hugging Face cache ({_hub_cache(cache_dir)}) and downloads "
            f"are off. Provide them by one of: `ctp models pull {name}` where the network allows it; `hf download "
            f"{name}` on a machine with network, then copy that cache here or point HF_HOME at it; save the model with "
            "save_pretrained and pass hf:/path/to/dir; or set CTP_ALLOW_DOWNLOAD=1 to let ctp download it")


def _missing_hf(name: str, cache_dir: str | None, offline: bool) -> str | None:
    if looks_local(name):
        folder = Path(name).expanduser()
        if not (folder / "config.json").is_file():
            return f"no transformers model directory at {folder} (expected config.json from save_pretrained)"
        if not any((folder / f).is_file() for f in WEIGHT_FILES):
            return f"{folder} has a config.json but no weights ({', '.join(WEIGHT_FILES)})"
        return None
    if not offline:
        return None
    from huggingface_hub import try_to_load_from_cache

    def cached(filename: str) -> bool:
        try:
            return isinstance(try_to_load_from_cache(name, filename, cache_dir=cache_dir), str)
        except ValueError:  # not a valid repository id: nothing of it can be cached
            return False

    if cached("config.json") and any(cached(f) for f in WEIGHT_FILES):
        return None
    return absent_message(name, cache_dir)


def _hub_cache(cache_dir: str | None) -> str:
    from huggingface_hub import constants

    return str(cache_dir or constants.HF_HUB_CACHE)
