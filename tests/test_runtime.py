"""Tests for the ONNX Runtime path of the guide (ctp_core.guide.runtime): export, cache, routing, fallback, int8,
the forward-only ``onnx:`` backend and the configuration's refusals. All on random:tiny (one export)."""

from __future__ import annotations

import logging

import pytest
import torch

from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError, ModelError
from ctp_core.guide import runtime
from ctp_core.guide.loaders import load_guide
from tests.test_guidance import _images, _save_tiny_hf_clip

PROMPTS = ["a cherry on top of a sundae", "a hat on a dog", "x"]


@pytest.fixture(scope="module")
def torch_guide():
    return load_guide("random:tiny", autocast=False)


@pytest.fixture(scope="module")
def onnx_guide():  # exports into the session's private cache (conftest)
    guide = load_guide("random:tiny", autocast=False, runtime="onnx", threads=1)
    assert guide.runtime == "onnx", "the export failed (see the log line)"
    return guide


def _count_calls(monkeypatch, encoders) -> list[int]:
    calls = [0]
    original = encoders.image_features

    def counted(pixels):
        calls[0] += 1
        return original(pixels)

    monkeypatch.setattr(encoders, "image_features", counted)
    return calls


def test_onnx_scores_match_torch(onnx_guide, torch_guide):
    images = _images(5, size=80)
    text = torch_guide.encode_text(PROMPTS)
    torch.testing.assert_close(onnx_guide.encode_text(PROMPTS), text, atol=1e-5, rtol=0)
    torch.testing.assert_close(onnx_guide.score(images, text), torch_guide.score(images, text), atol=1e-5, rtol=0)
    ref = _images(1, size=48)[0]
    torch.testing.assert_close(onnx_guide.encode_reference_image(ref), torch_guide.encode_reference_image(ref),
                               atol=1e-5, rtol=0)


def test_grad_decides_the_runtime(onnx_guide, monkeypatch):
    calls = _count_calls(monkeypatch, onnx_guide.encoders)
    images = _images(2, size=64)
    with torch.no_grad():
        onnx_guide.encode_images(images)
    with torch.inference_mode():
        onnx_guide.encode_images(images)
    assert calls[0] == 2
    leaf = images.clone().requires_grad_(True)
    emb = onnx_guide.encode_images(leaf)  # gradients enabled: torch, differentiable
    assert calls[0] == 2 and emb.requires_grad
    emb.sum().backward()
    assert leaf.grad.abs().sum() > 0


def test_cached_export_is_reused_not_redone(onnx_guide, monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("re-exported a cached model")

    monkeypatch.setattr(runtime, "_export", refuse)
    again = load_guide("random:tiny", autocast=False, runtime="onnx", threads=1)
    assert again.runtime == "onnx" and again.encoders.directory == onnx_guide.encoders.directory
    key = onnx_guide.encoders.meta["key"]
    assert key["spec"] == "random:tiny" and key["opset"] == runtime.OPSET and key["torch"] == torch.__version__
    other_weights = runtime.cache_dir({**key, "weights": "0" * 32})
    assert other_weights != onnx_guide.encoders.directory  # the weights hash is part of the key


def test_int8_is_close_and_quantises_only_the_vision_tower(onnx_guide, torch_guide):
    int8 = load_guide("random:tiny", autocast=False, runtime="onnx-int8", threads=1)
    assert int8.runtime == "onnx-int8"
    assert (int8.encoders.directory / runtime.VISION_INT8).is_file()
    images = _images(6, size=64)
    text = torch_guide.encode_text(PROMPTS)
    reference, quantised = torch_guide.score(images, text), int8.score(images, text)
    assert (reference - quantised).abs().max() < 0.05
    assert not torch.allclose(reference, quantised, atol=1e-6, rtol=0)  # it really ran int8
    torch.testing.assert_close(int8.encode_text(PROMPTS), text, atol=1e-5, rtol=0)  # text stays fp32


def test_export_failure_logs_one_line_and_stays_on_torch(tmp_path, monkeypatch, caplog, torch_guide):
    monkeypatch.setenv("CTP_ONNX_CACHE", str(tmp_path))

    def broken(*args, **kwargs):
        raise RuntimeError("exporter exploded\nsecond line of a long trace")

    monkeypatch.setattr(runtime, "_export", broken)
    with caplog.at_level(logging.WARNING):
        guide = load_guide("random:tiny", autocast=False, runtime="onnx")
    records = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(records) == 1 and "exporter exploded" in records[0].getMessage()
    assert "second line" not in records[0].getMessage()
    assert guide.runtime == "torch" and guide.encoders is None
    images = _images(2)
    text = torch_guide.encode_text(PROMPTS)
    torch.testing.assert_close(guide.score(images, text), torch_guide.score(images, text))
    assert not any(p.name.endswith(".onnx") for p in tmp_path.rglob("*"))  # no half-written export left


def test_session_failure_falls_back_to_torch(onnx_guide, monkeypatch, torch_guide):
    guide = load_guide("random:tiny", autocast=False, runtime="onnx", threads=1)

    def broken(pixels):
        raise RuntimeError("session died")

    monkeypatch.setattr(guide.encoders, "image_features", broken)
    images = _images(3)
    text = torch_guide.encode_text(PROMPTS)
    torch.testing.assert_close(guide.score(images, text), torch_guide.score(images, text))
    assert guide.runtime == "torch"


def test_onnx_directory_backend_is_forward_only(onnx_guide, torch_guide):
    spec = f"onnx:{onnx_guide.encoders.directory}"
    guide = load_guide(spec, runtime="onnx")
    assert not guide.differentiable and torch_guide.differentiable
    images = _images(4, size=72)
    text = torch_guide.encode_text(PROMPTS)
    torch.testing.assert_close(guide.encode_text(PROMPTS), text, atol=1e-5, rtol=0)
    torch.testing.assert_close(guide.score(images, text), torch_guide.score(images, text), atol=1e-5, rtol=0)
    with pytest.raises(ModelError, match="forward only"):
        guide.encode_images(images.requires_grad_(True))
    with pytest.raises(ModelError, match="no torch weights"):
        load_guide(spec, runtime="torch")


def test_hf_text_tower_exports_with_a_dynamic_sequence(tmp_path):
    """CLIP's tokenizer pads to the longest prompt: the exported text tower must take any length."""
    _save_tiny_hf_clip(tmp_path / "model")
    spec = f"hf:{tmp_path / 'model'}"
    reference = load_guide(spec, autocast=False, offline=True)
    guide = load_guide(spec, autocast=False, offline=True, runtime="onnx", threads=1)
    assert guide.runtime == "onnx"
    for prompts in (["a"], ["a cat", "a much longer prompt about a hat on a dog"]):
        torch.testing.assert_close(guide.encode_text(prompts), reference.encode_text(prompts), atol=1e-5, rtol=0)
    images = _images(2, size=40)
    with torch.no_grad():
        torch.testing.assert_close(guide.encode_images(images), reference.encode_images(images), atol=1e-5, rtol=0)
    forward_only = load_guide(f"onnx:{guide.encoders.directory}", runtime="onnx")  # tokenizer saved with it
    torch.testing.assert_close(forward_only.encode_text(["a red ball"]), reference.encode_text(["a red ball"]),
                               atol=1e-5, rtol=0)


def test_optimiser_selection_uses_onnx_runtime(onnx_guide, monkeypatch):
    import trimesh

    from ctp_core.align import align

    calls = _count_calls(monkeypatch, onnx_guide.encoders)
    config = AlignConfig.from_preset("test", model="random:tiny", runtime="onnx")
    result = align(trimesh.creation.box((2, 0.2, 2)), trimesh.creation.icosphere(1, 0.3), "a ball on a table",
                   config, guide=onnx_guide)
    assert calls[0] > 0  # the evaluations on fixed views ran forward-only in ONNX Runtime
    assert result.runtime == "onnx"


def test_auto_rule():
    assert runtime.resolve("auto", device="cpu", bf16=False) == "onnx"
    assert runtime.resolve("auto", device="cpu", bf16=True) == "torch"
    assert runtime.resolve("auto", device="cuda", bf16=True) == "torch"
    assert runtime.resolve("onnx-int8", device="cpu", bf16=True) == "onnx-int8"


def test_config_refuses_runs_a_backend_cannot_serve():
    with pytest.raises(ConfigError, match="forward only") as info:
        AlignConfig.from_preset("test", model="onnx:/models/clip")
    assert info.value.field == "model"
    AlignConfig.from_preset("test", model="onnx:/models/clip", loss={"selection_only": True})
    AlignConfig.from_preset("test", model="onnx:/models/clip", loss={"lambda_clip": 0.0})
    with pytest.raises(ConfigError, match="ONNX Runtime") as info:
        AlignConfig.from_preset("test", model="onnx:/models/clip", runtime="torch", loss={"selection_only": True})
    assert info.value.field == "runtime"
    with pytest.raises(ConfigError, match="CPU") as info:
        AlignConfig.from_preset("test", model="random:tiny", runtime="onnx", device="cuda")
    assert info.value.field == "runtime"
    with pytest.raises(ConfigError, match="runtime"):
        AlignConfig.from_preset("test", runtime="tensorrt")
    assert AlignConfig.from_preset("test").runtime == "auto"


def test_cli_forward_only_model_needs_selection_only(onnx_guide, tmp_path, capsys):
    import json

    import trimesh

    from ctp.cli import main

    target, source = tmp_path / "t.glb", tmp_path / "s.glb"
    trimesh.creation.box((2, 0.2, 2)).export(target)
    trimesh.creation.icosphere(1, 0.3).export(source)
    argv = ["align", str(target), str(source), "--prompt", "a ball on a table", "--preset", "test", "--quiet",
            "--model", f"onnx:{onnx_guide.encoders.directory}", "--out", str(tmp_path / "o.glb")]
    assert main(argv) == 2
    assert "forward only" in capsys.readouterr().err
    assert main([*argv, "--selection-only", "--runtime", "onnx"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["runtime"] == "onnx"
