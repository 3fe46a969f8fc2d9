"""Tests for ctp_core.guide.guidance: random and local hf backends, numerics, and the refusals."""

from __future__ import annotations

import importlib.util
import time

import numpy as np
import pytest
import torch

from ctp_core.config import backends
from ctp_core.errors import ModelError
from ctp_core.guide import guidance, loaders
from ctp_core.guide.checkpoints import downloads_allowed
from ctp_core.guide.guidance import ImageTransform, byte_tokenize
from ctp_core.guide.loaders import get_guide, load_guide


@pytest.fixture(scope="module")
def tiny():
    return load_guide("random:tiny", autocast=False)


@pytest.fixture(scope="module")
def tiny_bf16():
    """bf16 autocast forced on, whatever this CPU is: its numerics are tested here, its speed is benchmarked."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(guidance, "cpu_has_fast_bf16", lambda: True)
        return load_guide("random:tiny", autocast=True)


def test_cpu_autocast_follows_native_bf16_support(monkeypatch):
    for native in (False, True):
        monkeypatch.setattr(guidance, "cpu_has_fast_bf16", lambda native=native: native)
        assert load_guide("random:tiny", autocast=True).autocast is native
    assert load_guide("random:tiny", autocast=False).autocast is False


def _images(n: int, size: int = 96, seed: int = 0) -> torch.Tensor:
    """Smooth coloured blobs on white, like renders: random noise would sit far from any real input."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.linspace(-1, 1, size), torch.linspace(-1, 1, size), indexing="ij")
    centre = torch.rand(n, 2, 1, 1, generator=g) - 0.5
    mask = (((xx - centre[:, :1]) ** 2 + (yy - centre[:, 1:]) ** 2) < 0.2).float()
    colour = torch.rand(n, 3, 1, 1, generator=g)
    return mask * colour + (1 - mask)


def test_random_weights_are_deterministic_and_leave_global_rng_alone(tiny):
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    other = load_guide("random:tiny", autocast=False)
    assert torch.equal(torch.rand(3), expected)
    texts = ["a cherry on top of a sundae", "a hat on a dog"]
    assert torch.equal(tiny.encode_text(texts), other.encode_text(texts))
    assert torch.equal(tiny.encode_images(_images(2)), other.encode_images(_images(2)))


def test_embeddings_are_unit_norm_with_the_declared_dim(tiny):
    text = tiny.encode_text(["a", "a much longer prompt " * 10])  # the second is truncated to 77 tokens
    img = tiny.encode_images(_images(3, size=50))
    ref = tiny.encode_reference_image(_images(1)[0])
    for emb in (text, img, ref[None]):
        assert emb.shape[-1] == tiny.embed_dim
        torch.testing.assert_close(emb.norm(dim=-1), torch.ones(emb.shape[0]))
    assert not text.requires_grad


def test_text_embeddings_tell_prompts_apart(tiny):
    a, b = tiny.encode_text(["a cat on a mat", "a dog on a log"])
    assert a @ b < 0.9999


@pytest.mark.parametrize("autocast", [False, True])
def test_gradient_reaches_the_images(autocast, monkeypatch):
    monkeypatch.setattr(guidance, "cpu_has_fast_bf16", lambda: True)
    guide = load_guide("random:tiny", autocast=autocast)
    assert guide.autocast is autocast
    images = _images(2, size=80).requires_grad_(True)
    text = guide.encode_text(["a red ball"])[0]
    (guide.encode_images(images) @ text).sum().backward()
    assert torch.isfinite(images.grad).all()
    assert images.grad.abs().sum() > 0
    assert not any(p.grad is not None for p in guide.model.parameters())


def test_score_is_the_cosine_of_the_encodings(tiny):
    images = _images(5)
    texts = tiny.encode_text(["a red ball", "a blue cube"])
    with torch.no_grad():
        expected = tiny.encode_images(images) @ texts.T
    torch.testing.assert_close(tiny.score(images, texts[0], batch_size=2), expected[:, 0], atol=1e-5, rtol=0)
    both = tiny.score(images, texts, batch_size=3)
    assert both.shape == (5, 2) and not both.is_inference()
    torch.testing.assert_close(both, expected, atol=1e-5, rtol=0)


def test_bf16_autocast_stays_close_to_fp32(tiny, tiny_bf16):
    images = _images(8, size=224)
    texts = tiny.encode_text(["a cherry on top of a sundae", "a lamp on a desk", "an arrow in a target"])
    cos32 = tiny.score(images, texts)
    cos16 = tiny_bf16.score(images, texts)
    assert (cos32 - cos16).abs().max() < 1e-2
    assert not torch.equal(cos32, cos16)  # autocast really ran in bf16


def test_reference_image_forms_agree(tiny):
    rgb = (_images(1, size=64)[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    from_uint8 = tiny.encode_reference_image(rgb)
    from_float = tiny.encode_reference_image(rgb.astype(np.float32) / 255)
    from_tensor = tiny.encode_reference_image(torch.from_numpy(rgb).permute(2, 0, 1).float() / 255)
    torch.testing.assert_close(from_uint8, from_float)
    torch.testing.assert_close(from_uint8, from_tensor)
    transparent = np.concatenate([np.zeros_like(rgb), np.zeros_like(rgb[:, :, :1])], axis=2)
    white = tiny.encode_reference_image(np.full_like(rgb, 255))
    torch.testing.assert_close(tiny.encode_reference_image(transparent), white)
    with pytest.raises(ValueError):
        tiny.encode_reference_image(np.zeros((4, 4, 2), np.uint8))


def test_transform_resizes_short_side_then_centre_crops():
    t = ImageTransform.clip(32, mean=(0.0,) * 3, std=(1.0,) * 3)
    # A 32 x 64 image: no resize needed, the crop must keep columns 16..47.
    x = torch.arange(64.0).expand(1, 3, 32, 64) / 64
    out = t(x)
    assert out.shape == (1, 3, 32, 32)
    torch.testing.assert_close(out[0, 0, 0], torch.arange(16.0, 48.0) / 64)
    assert t(torch.rand(2, 3, 100, 60)).shape == (2, 3, 32, 32)


def test_transform_reads_an_align_style_processor_config():
    # EfficientNet/ALIGN: rescale by 1/127.5 with offset -1, no mean/std: pixels map to 2x - 1.
    cfg = {"size": {"height": 40, "width": 40}, "do_center_crop": True, "crop_size": {"height": 30, "width": 30},
           "rescale_factor": 1 / 127.5, "rescale_offset": True, "do_normalize": False}
    t = ImageTransform.from_processor_config(cfg)
    x = torch.full((1, 3, 20, 20), 0.25)
    out = t(x)
    assert out.shape == (1, 3, 30, 30)
    torch.testing.assert_close(out, torch.full_like(out, -0.5))


def test_byte_tokenizer_layout():
    batch = byte_tokenize(["ab", "x" * 200], vocab_size=300)
    ids, mask = batch["input_ids"], batch["attention_mask"]
    assert ids.shape == (2, 77)
    assert ids[0, :4].tolist() == [298, ord("a"), ord("b"), 299]
    assert mask[0].sum() == 4 and mask[1].sum() == 77 and ids[1, -1] == 299


def _save_tiny_hf_clip(path):
    """A small random CLIPModel + a byte-level CLIP BPE tokenizer + processor config, all built offline."""
    from tokenizers import pre_tokenizers
    from transformers import CLIPConfig, CLIPModel, CLIPTokenizer

    vocab = {}
    for ch in sorted(pre_tokenizers.ByteLevel.alphabet()):
        vocab[ch] = len(vocab)
        vocab[ch + "</w>"] = len(vocab)
    vocab["<|startoftext|>"] = len(vocab)
    vocab["<|endoftext|>"] = len(vocab)
    tokenizer = CLIPTokenizer(vocab=vocab, merges=[])
    text = {"hidden_size": 32, "intermediate_size": 64, "num_hidden_layers": 1, "num_attention_heads": 2,
            "vocab_size": len(vocab), "bos_token_id": tokenizer.bos_token_id,
            "eos_token_id": tokenizer.eos_token_id, "pad_token_id": tokenizer.pad_token_id}
    vision = {"hidden_size": 32, "intermediate_size": 64, "num_hidden_layers": 1, "num_attention_heads": 2,
              "patch_size": 8, "image_size": 32}
    torch.manual_seed(0)
    model = CLIPModel(CLIPConfig(text_config=text, vision_config=vision, projection_dim=16)).eval()
    model.save_pretrained(path)
    tokenizer.save_pretrained(path)
    (path / "preprocessor_config.json").write_text(
        '{"size": {"shortest_edge": 32}, "do_center_crop": true, "crop_size": {"height": 32, "width": 32},'
        ' "image_mean": [0.5, 0.4, 0.3], "image_std": [0.2, 0.25, 0.3], "rescale_factor": 0.00392156862745098}'
    )
    return model, tokenizer


def test_hf_local_directory_loads_offline_and_matches_the_model(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    model, tokenizer = _save_tiny_hf_clip(tmp_path)
    guide = load_guide(f"hf:{tmp_path}", autocast=False, offline=True, cache_dir=str(tmp_path / "cache"))
    assert guide.embed_dim == 16
    prompts = ["a cat", "a hat on a dog"]
    batch = tokenizer(prompts, padding=True, return_tensors="pt")
    with torch.no_grad():
        expected_text = loaders._pooled(model.get_text_features(**batch))
        pixels = (_images(2, size=32) - torch.tensor([0.5, 0.4, 0.3]).view(1, 3, 1, 1)) / torch.tensor(
            [0.2, 0.25, 0.3]).view(1, 3, 1, 1)
        expected_img = loaders._pooled(model.get_image_features(pixel_values=pixels))
    torch.testing.assert_close(guide.encode_text(prompts), torch.nn.functional.normalize(expected_text, dim=-1))
    torch.testing.assert_close(guide.encode_images(_images(2, size=32)),
                               torch.nn.functional.normalize(expected_img, dim=-1))


def test_hf_repo_name_loads_from_the_cache_offline(tmp_path):
    # The Hugging Face cache layout: models--ORG--NAME/{refs/main, snapshots/REVISION/...}.
    repo = tmp_path / "models--ctp-test--tiny-clip"
    revision = "0" * 40
    snapshot = repo / "snapshots" / revision
    snapshot.mkdir(parents=True)
    _save_tiny_hf_clip(snapshot)
    (snapshot / "preprocessor_config.json").unlink()  # falls back to CLIP's recipe at the model's size
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(revision)
    guide = load_guide("hf:ctp-test/tiny-clip", offline=True, cache_dir=str(tmp_path))
    assert guide.transform == ImageTransform.clip(32)
    assert guide.encode_images(_images(1, size=48)).shape == (1, 16)


def test_missing_offline_weights_fail_fast_with_instructions(tmp_path):
    start = time.monotonic()
    with pytest.raises(ModelError) as info:
        load_guide("hf:openai/clip-vit-base-patch32", offline=True, cache_dir=str(tmp_path))
    assert time.monotonic() - start < 5
    assert info.value.code == "model_unavailable"
    assert "openai/clip-vit-base-patch32" in info.value.message
    assert "CTP_ALLOW_DOWNLOAD" in info.value.message and "hf download" in info.value.message


@pytest.mark.parametrize(
    ("spec", "fragment"),
    [
        ("clip-vit", "must look like"),
        ("onnx:model", "no exported model"),
        ("tensorrt:model", "unknown model backend"),
        ("random:ViT-Z-99", "unknown random architecture"),
        ("open_clip:ViT-B-32", "open_clip:ARCH:TAG"),
        ("hf:/nonexistent/ctp-model", "no transformers model directory"),
    ],
)
def test_bad_specs_raise_model_error(spec, fragment):
    with pytest.raises(ModelError, match=fragment):
        load_guide(spec)


def test_every_backend_has_one_loader():
    """``backends`` (torch-free, for validation) and ``loaders.LOADERS`` name the same prefixes."""
    assert set(loaders.LOADERS) == set(backends.BACKENDS)


def test_cuda_without_a_gpu_is_a_model_error():
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present; this checks the refusal without one")
    with pytest.raises(ModelError, match="CUDA"):
        load_guide("random:tiny", device="cuda")


def test_open_clip_absent_suggests_the_hf_spec():
    if importlib.util.find_spec("open_clip") is not None:
        pytest.skip("open_clip is installed here; this checks the message when it is absent")
    with pytest.raises(ModelError, match="hf:openai/clip-vit-base-patch32"):
        load_guide("open_clip:ViT-B-32:openai")


@pytest.mark.parametrize(
    ("env", "allowed"),
    [
        ({}, False),
        ({"CTP_ALLOW_DOWNLOAD": "1"}, True),
        ({"CTP_ALLOW_DOWNLOAD": "0", "HF_HUB_OFFLINE": "0"}, False),
        ({"HF_HUB_OFFLINE": "0"}, True),
        ({"HF_HUB_OFFLINE": "1"}, False),
    ],
)
def test_downloads_allowed_follows_the_environment(monkeypatch, env, allowed):
    for name in ("CTP_ALLOW_DOWNLOAD", "HF_HUB_OFFLINE"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert downloads_allowed() is allowed


def test_get_guide_loads_once_per_arguments():
    first = get_guide("random:tiny")
    assert get_guide("random:tiny", device="cpu", autocast=True) is first
    assert get_guide("random:tiny", autocast=False) is not first


def test_vit_b_32_forward_shapes():
    guide = load_guide("random:ViT-B-32")
    assert guide.embed_dim == 512 and guide.transform.crop == (224, 224)
    emb = guide.encode_images(_images(1, size=64))
    assert emb.shape == (1, 512) and torch.isfinite(emb).all()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device: fp16 autocast path not exercised")
def test_cuda_fp16_matches_cpu_fp32(tiny):
    guide = load_guide("random:tiny", device="cuda")
    text = tiny.encode_text(["a red ball"])
    images = _images(4, size=224)
    gpu = guide.score(images.cuda(), text[0].cuda()).cpu()
    torch.testing.assert_close(gpu, tiny.score(images, text[0]), atol=1e-2, rtol=0)
