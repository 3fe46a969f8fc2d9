"""Where weights are, decided without loading them: what readiness and ``ctp serve``'s start-up line rely on."""

from __future__ import annotations

import subprocess
import sys

import pytest

from ctp_core.guide import checkpoints
from tests.conftest import REPO


@pytest.fixture(autouse=True)
def offline(monkeypatch):
    monkeypatch.delenv("CTP_ALLOW_DOWNLOAD", raising=False)
    monkeypatch.delenv("HF_HUB_OFFLINE", raising=False)


def hub_cache(root, repo: str, files: list[str]):
    """The Hugging Face cache layout (refs/main -> snapshots/REV/FILE) of ``repo`` with these files."""
    folder = root / f"models--{repo.replace('/', '--')}"
    (folder / "refs").mkdir(parents=True)
    (folder / "refs" / "main").write_text("0123abcd")
    snapshot = folder / "snapshots" / "0123abcd"
    snapshot.mkdir(parents=True)
    for name in files:
        (snapshot / name).write_text("{}")
    return root


def test_hub_repository_present_only_with_config_and_weights(tmp_path):
    full = hub_cache(tmp_path / "full", "acme/clip", ["config.json", "model.safetensors"])
    assert checkpoints.missing("hf:acme/clip", cache_dir=str(full)) is None
    bare = hub_cache(tmp_path / "bare", "acme/clip", ["config.json"])
    message = checkpoints.missing("hf:acme/clip", cache_dir=str(bare))
    assert message.startswith("weights for 'acme/clip' are not in the Hugging Face cache")
    assert "downloads are off" in message and "CTP_ALLOW_DOWNLOAD=1" in message and "connect" not in message


def test_downloads_allowed_counts_as_present(tmp_path, monkeypatch):
    monkeypatch.setenv("CTP_ALLOW_DOWNLOAD", "1")
    assert checkpoints.missing("hf:acme/clip", cache_dir=str(tmp_path)) is None


def test_local_folders_and_other_backends(tmp_path):
    assert "no transformers model directory" in checkpoints.missing(f"hf:{tmp_path / 'none'}")
    (tmp_path / "config.json").write_text("{}")
    assert "no weights" in checkpoints.missing(f"hf:{tmp_path}")
    (tmp_path / "pytorch_model.bin").write_bytes(b"")
    assert checkpoints.missing(f"hf:{tmp_path}") is None
    assert checkpoints.missing("random:tiny") is None  # no weights to miss
    assert "checkpoint file" in checkpoints.missing("open_clip:ViT-B-32:openai")
    assert checkpoints.missing("hf:not a repo id!") is not None  # invalid ids are simply not cached


def test_checking_imports_no_torch():
    code = ("import sys; from ctp_core.guide import checkpoints; "
            "checkpoints.missing('hf:acme/clip'); print('torch' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert run.stdout.strip() == "False", run.stderr
