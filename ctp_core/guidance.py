"""Vision-language guidance: one small interface over CLIP-like models.

The optimiser needs three things from a vision-language model: a text (or reference image) embedding
computed once per run, image embeddings of rendered views that carry gradients back to the pixels,
and cheap forward-only scores for selecting restarts. ``Guide`` gives exactly that, whatever the
backend, and does the model's own resizing and mean/std normalisation inside, so callers pass plain
renders ``(N, 3, H, W)`` in [0, 1] at any resolution.

Model specs (the strings of ``ctp align --model``):

- ``hf:REPO_OR_PATH``: a transformers ``CLIPModel`` / ``SiglipModel`` / ``AlignModel`` with its own
  tokenizer, from a local directory (``save_pretrained`` output) or the Hugging Face cache. This is the
  real-weights backend: transformers needs no torchvision, and has SigLIP and ALIGN, which the
  paper's metrics use.
- ``open_clip:ARCH:TAG``: only when ``open_clip`` is importable. It is not installed here: it imports
  torchvision, whose PyPI build does not import beside the CPU torch on disk. ``TAG`` may be a
  checkpoint path.
- ``random:ARCH``: the same architecture with deterministic random weights (seeded, built from a
  config in code, nothing read or downloaded) for tests and benchmarks on machines without weights.
  ``ARCH`` is one of ``RANDOM_ARCHS`` (``ViT-B-32``, ``ViT-B-16``, ``ViT-L-14``, ``tiny``).
- ``onnx:DIR``: a directory of exported towers (an entry of the ONNX cache, see ``runtime``), run by
  ONNX Runtime without torch weights. Forward only: ``Guide.differentiable`` is False, and a run that
  needs image gradients is refused when it is configured (``config``).

The backends are a registry (``backends.BACKENDS``: spec prefix -> loader, differentiable or not).

Runtime of the forward-only calls (``runtime``: ``auto``, ``torch``, ``onnx``, ``onnx-int8``): with
``onnx``/``onnx-int8`` the guide exports its towers once (cached) and runs ``encode_images``,
``score`` and ``encode_reference_image`` in ONNX Runtime whenever gradients are disabled
(``torch.no_grad`` / ``torch.inference_mode``; ``encode_text`` always is), and in torch whenever they
are enabled, so the optimiser's gradient path is unchanged. If export or loading fails the guide logs
one line and stays on torch. ``auto`` follows ``runtime.resolve`` (measured; README).

Offline by default: weights are only read from disk unless the caller passes ``offline=False`` or
the environment allows downloads (``CTP_ALLOW_DOWNLOAD=1``, or ``HF_HUB_OFFLINE=0``). Missing
weights raise ``ModelError`` at once, naming them and how to provide them; nothing waits on a network.

Precision: images go through the model under bf16 autocast on CPU and fp16 autocast on CUDA when
``autocast`` is on; text and reference images are always encoded in fp32 (once per run, so precision
costs nothing there). Decision measured with ``benchmarks/guidance_bench.py --spec random:ViT-B-32``
on the shared 2-core AVX512-BF16 CPU (two runs, load 1 and 3-7, so ratios within a run are what
counts): max |cos_bf16 - cos_fp32| = 5.3e-4 over 512 image-text pairs (bound 1e-2), gradient w.r.t.
the pixels has cosine 0.99997 with fp32's; forward+backward of 8 views at 224 px 1.15 -> 0.83 s
(1.4x; 1.6x in the loaded run), forward-only 94 -> 54 ms per image (1.75x; 2.4x loaded). On a CPU
without native bf16 (an AMD EPYC worker with AVX2 only, no AVX512-BF16/AMX) the same benchmark gave
fp32 2.35 s vs bf16 86 s (bf16 emulated, 37x slower). So bf16 is on by default on CPU only where the CPU
has AVX512-BF16 or AMX (``cpu_has_fast_bf16``); elsewhere the CPU path is fp32. The model's weights
are frozen (``requires_grad_(False)``) so the backward pass computes pixel gradients only: fp32
forward+backward 1.6x faster than with trainable weights
(interleaved in one run), likely why 1.15 s here beats the 2.0 s measured earlier. ``random:tiny``
is too small to gain from bf16 (autocast overhead makes it ~1.5x slower); it exists for CI.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ctp_core import backends
from ctp_core import runtime as runtime_mod
from ctp_core.errors import ModelError, ModelSpecError
from ctp_core.weights import downloads_allowed, looks_local, missing

log = logging.getLogger(__name__)

# CLIP's (OpenAI) pixel statistics; open_clip and transformers CLIP checkpoints use the same.
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)

def _clip_shape(width: int, layers: int, heads: int, patch: int, text_width: int, text_heads: int, *,
                image_size: int = 224, text_layers: int = 12, vocab: int = 49408, mlp_ratio: int = 4) -> dict:
    """transformers CLIPConfig keyword arguments of a ViT CLIP (the projection is the text width)."""
    return {
        "vision": {"hidden_size": width, "intermediate_size": mlp_ratio * width, "num_hidden_layers": layers,
                   "num_attention_heads": heads, "patch_size": patch, "image_size": image_size},
        "text": {"hidden_size": text_width, "intermediate_size": mlp_ratio * text_width,
                 "num_hidden_layers": text_layers, "num_attention_heads": text_heads, "vocab_size": vocab},
        "projection_dim": text_width,
    }


# Random architectures: transformers CLIPConfig keyword arguments. The ViT entries match OpenAI CLIP's
# shapes so timings and memory are those of the real model; ``tiny`` is small enough for CI.
RANDOM_ARCHS: dict[str, dict] = {
    "ViT-B-32": _clip_shape(768, 12, 12, 32, 512, 8),
    "ViT-B-16": _clip_shape(768, 12, 12, 16, 512, 8),
    "ViT-L-14": _clip_shape(1024, 24, 16, 14, 768, 12),
    "tiny": _clip_shape(64, 2, 2, 16, 64, 2, image_size=64, text_layers=2, vocab=258, mlp_ratio=2),
}
RANDOM_SEED = 0
TEXT_CONTEXT = 77  # CLIP's text context length, SOT and EOT included

# open_clip (ARCH, TAG) -> the transformers checkpoint holding the same weights, for error messages.
OPEN_CLIP_TO_HF = {
    ("ViT-B-32", "openai"): "openai/clip-vit-base-patch32",
    ("ViT-B-16", "openai"): "openai/clip-vit-base-patch16",
    ("ViT-L-14", "openai"): "openai/clip-vit-large-patch14",
    ("ViT-L-14-336", "openai"): "openai/clip-vit-large-patch14-336",
    ("ViT-B-32", "laion2b_s34b_b79k"): "laion/CLIP-ViT-B-32-laion2B-s34B-b79K",
    ("ViT-L-14", "laion2b_s32b_b82k"): "laion/CLIP-ViT-L-14-laion2B-s32B-b82K",
    ("ViT-H-14", "laion2b_s32b_b79k"): "laion/CLIP-ViT-H-14-laion2B-s32B-b79K",
}


@dataclass(frozen=True)
class ImageTransform:
    """A model's pixel pipeline, in torch so it is differentiable: resize, centre crop, normalise.

    ``resize`` is either ``("shortest_edge", S)`` (scale so the short side is S, as CLIP does) or
    ``("size", (H, W))`` (squash to H x W, as SigLIP does); ``crop`` is the centre crop (H, W) or None.
    ``mean``/``std`` are per channel in [0, 1] pixel units (any rescale offset folded in).
    """

    resize: tuple[str, int | tuple[int, int]]
    crop: tuple[int, int] | None
    mean: tuple[float, float, float]
    std: tuple[float, float, float]

    @classmethod
    def clip(cls, size: int, mean=CLIP_MEAN, std=CLIP_STD) -> ImageTransform:
        """CLIP's recipe: short side to ``size``, centre crop ``size`` x ``size``."""
        return cls(("shortest_edge", size), (size, size), tuple(mean), tuple(std))

    @classmethod
    def from_processor_config(cls, cfg: dict) -> ImageTransform:
        """Read a transformers ``preprocessor_config.json`` (CLIP, SigLIP and EfficientNet/ALIGN)."""
        size = cfg.get("size", 224)
        if isinstance(size, int):
            resize = ("shortest_edge", size)
        elif "shortest_edge" in size:
            resize = ("shortest_edge", int(size["shortest_edge"]))
        else:
            resize = ("size", (int(size["height"]), int(size["width"])))
        crop = None
        if cfg.get("do_center_crop", False):
            c = cfg.get("crop_size", size)
            crop = (c, c) if isinstance(c, int) else (int(c["height"]), int(c["width"]))
        # pixel_model = ((x * 255 * rescale) - offset - mean) / std with x in [0, 1]; fold it into
        # mean/std in [0, 1] units so one affine map does it.
        a = 255.0 * cfg.get("rescale_factor", 1 / 255) if cfg.get("do_rescale", True) else 255.0
        b = 1.0 if cfg.get("rescale_offset", False) else 0.0
        normalise = cfg.get("do_normalize", True)
        mean = cfg.get("image_mean", CLIP_MEAN) if normalise else (0.0, 0.0, 0.0)
        std = cfg.get("image_std", CLIP_STD) if normalise else (1.0, 1.0, 1.0)
        return cls(resize, crop, tuple((b + m) / a for m in mean), tuple(s / a for s in std))

    def __call__(self, images: Tensor) -> Tensor:
        """(N, 3, H, W) in [0, 1] -> (N, 3, h, w) model input, fp32; gradients flow to ``images``."""
        x = images.float()
        h, w = x.shape[-2:]
        kind, value = self.resize
        if kind == "shortest_edge":
            short, long = (h, w) if h <= w else (w, h)
            long = int(value * long / short)
            out = (value, long) if h <= w else (long, value)
        else:
            out = value
        if tuple(out) != (h, w):
            x = F.interpolate(x, size=out, mode="bilinear", align_corners=False, antialias=True)
        if self.crop is not None:
            ch, cw = self.crop
            top, left = max(0, (x.shape[-2] - ch) // 2), max(0, (x.shape[-1] - cw) // 2)
            x = x[..., top:top + ch, left:left + cw]
        mean = x.new_tensor(self.mean).view(1, 3, 1, 1)
        std = x.new_tensor(self.std).view(1, 3, 1, 1)
        return (x - mean) / std


def cpu_has_fast_bf16() -> bool:
    """Whether this CPU computes bf16 natively (AVX512-BF16 or AMX); without it autocast emulates bf16, slowly."""
    probes = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(bool(getattr(torch.cpu, name, lambda: False)()) for name in probes)


Tokens = dict[str, Tensor]


@dataclass(frozen=True)
class LoadRequest:
    """What every backend loader gets besides the spec (see ``load_guide``)."""

    device: torch.device
    autocast: bool
    offline: bool
    cache_dir: str | None
    runtime: str
    threads: int


class Guide:
    """A loaded vision-language model; load once per process (``get_guide``) and reuse across jobs.

    Embeddings are (N, D) fp32 and L2-normalised, so a dot product is the cosine similarity.
    ``model`` is None for a forward-only backend (``onnx:``), whose calls all go to ``encoders``.
    ``tokenize`` maps prompts to the token tensors ``text_features`` takes; ``save_tokenizer`` writes
    what ``onnx:DIR`` needs to tokenize again into an export directory and returns its meta entry.
    """

    def __init__(
        self,
        spec: str,
        model: torch.nn.Module | None,
        *,
        image_features: Callable[[Tensor], Tensor] | None,
        tokenize: Callable[[list[str]], Tokens],
        text_features: Callable[[Tokens], Tensor] | None,
        transform: ImageTransform,
        embed_dim: int,
        device: torch.device,
        autocast: bool,
        save_tokenizer: Callable[[Path], dict] | None = None,
        encoders: runtime_mod.Encoders | None = None,
    ):
        self.spec = spec
        self.model = model.eval().requires_grad_(False) if model is not None else None  # pixel gradients only
        self.embed_dim = embed_dim
        self.device = device
        self.autocast = autocast and (device.type == "cuda" or (device.type == "cpu" and cpu_has_fast_bf16()))
        self.transform = transform
        self._image_features = image_features
        self._tokenize = tokenize
        self._text_features = text_features
        self._save_tokenizer = save_tokenizer
        self.encoders = encoders
        self.runtime = ("onnx-int8" if encoders.int8 else "onnx") if encoders is not None else "torch"

    def __repr__(self) -> str:
        return (f"Guide({self.spec!r}, device={self.device}, autocast={self.autocast}, runtime={self.runtime}, "
                f"D={self.embed_dim})")

    @property
    def differentiable(self) -> bool:
        """Whether ``encode_images`` can carry gradients back to the pixels (a torch model is loaded)."""
        return self.model is not None

    @property
    def amp_dtype(self) -> torch.dtype:
        """bf16 on CPU (fast with AVX512-BF16/AMX, error measured in the module docstring), fp16 on CUDA."""
        return torch.bfloat16 if self.device.type == "cpu" else torch.float16

    @torch.no_grad()
    def encode_text(self, texts: list[str]) -> Tensor:
        """(N, D) unit embeddings of raw prompts, fp32, no grad (ONNX Runtime when the runtime is onnx).

        ``no_grad`` rather than ``inference_mode``: the result enters the differentiable loss, and
        inference tensors cannot be saved for backward.
        """
        if isinstance(texts, str):
            texts = [texts]
        tokens = self._tokenize(list(texts))
        features = self._forward_only(lambda enc: enc.text_features(tokens), True)
        if features is None:
            features = self._text_features(tokens)
        return F.normalize(features.float().to(self.device), dim=-1)

    def encode_images(self, images: Tensor) -> Tensor:
        """(N, 3, H, W) in [0, 1], any size -> (N, D) unit embeddings, differentiable w.r.t. ``images``.

        With gradients disabled and an ONNX runtime, the forward pass runs in ONNX Runtime.
        """
        if images.dim() != 4 or images.shape[1] != 3:
            raise ValueError(f"images must be (N, 3, H, W), got {tuple(images.shape)}")
        return F.normalize(self._pixel_features(self.transform(images.to(self.device))).float(), dim=-1)

    def score(self, images: Tensor, text_emb: Tensor, batch_size: int = 32) -> Tensor:
        """Cosine of each image with ``text_emb`` ((D,) -> (N,); (T, D) -> (N, T)), forward only.

        Batches of ``batch_size`` bound memory when scoring many views; runs under inference_mode.
        """
        with torch.inference_mode():
            emb = text_emb.to(self.device, torch.float32)
            emb = emb.T if emb.dim() == 2 else emb
            out = torch.cat([self.encode_images(chunk) @ emb for chunk in images.split(batch_size)])
        return out.clone()  # a normal tensor, so callers may use it outside inference mode

    @torch.no_grad()
    def encode_reference_image(self, image: np.ndarray | Tensor) -> Tensor:
        """(D,) embedding of a reference picture for image-guided alignment, fp32.

        Accepts an (H, W, 3|4) or (H, W) array (uint8 0-255 or float 0-1, as PIL/imageio give) or a
        (3, H, W) tensor in [0, 1]. Alpha is composited over white, the renders' background, so a
        cut-out reference is compared like for like. fp32 (no autocast): encoded once per run.
        """
        if isinstance(image, Tensor):
            if image.dim() != 3 or image.shape[0] != 3:
                raise ValueError(f"a reference tensor must be (3, H, W), got {tuple(image.shape)}")
            x = image.float()
        else:
            arr = np.asarray(image)
            arr = arr.astype(np.float32) / 255.0 if arr.dtype == np.uint8 else arr.astype(np.float32)
            if arr.ndim == 2:
                arr = np.repeat(arr[:, :, None], 3, axis=2)
            if arr.ndim != 3 or arr.shape[2] not in (3, 4):
                raise ValueError(f"a reference image must be (H, W, 3|4) or (H, W), got {arr.shape}")
            if arr.shape[2] == 4:
                arr = arr[:, :, :3] * arr[:, :, 3:] + (1.0 - arr[:, :, 3:])
            x = torch.from_numpy(np.ascontiguousarray(arr.transpose(2, 0, 1)))
        pixels = self.transform(x.clamp(0, 1)[None].to(self.device))
        return F.normalize(self._pixel_features(pixels, amp=False).float(), dim=-1)[0]

    def use_runtime(self, runtime: str, threads: int) -> None:
        """Switch the forward-only calls to ``runtime`` (``runtime.RUNTIMES``), exporting once if needed.

        A failed export or load logs one line and leaves the guide on torch.
        """
        if self.model is None:  # a forward-only backend: its loader opened the sessions
            return
        resolved = runtime_mod.resolve(runtime, device=self.device.type, bf16=self.autocast)
        self.encoders, self.runtime = None, "torch"
        if resolved == "torch":
            return
        try:
            if self.device.type != "cpu":
                raise ValueError("ONNX Runtime runs on the CPU here; use the torch runtime on CUDA")
            key = runtime_mod.cache_key(self.spec, runtime_mod.weights_hash(self.model))
            meta = {"key": key, "embed_dim": self.embed_dim, "transform": asdict(self.transform)}
            directory = runtime_mod.export(
                runtime_mod.cache_dir(key), self.model, meta=meta, image_features=self._image_features,
                text_features=self._text_features,
                pixels=self.transform(torch.rand(2, 3, 64, 64)),  # the model input of square renders
                tokens=self._tokenize(["a photo of a cat", "a hat on a dog"]), save_tokenizer=self._save_tokenizer)
            self.encoders = runtime_mod.Encoders.load(directory, int8=resolved == "onnx-int8", threads=threads)
            self.runtime = resolved
        except Exception as exc:  # the exporter and onnxruntime raise many types; torch still works
            self._runtime_failed(resolved, exc)

    def _pixel_features(self, pixels: Tensor, amp: bool = True) -> Tensor:
        """Features of model-input pixels: ONNX Runtime when forward-only, else torch (autocast if on)."""
        features = self._forward_only(lambda enc: enc.image_features(pixels) if enc.accepts(pixels) else None,
                                      not torch.is_grad_enabled() or not pixels.requires_grad)
        if features is not None:
            return features.to(self.device)
        if self.model is None:
            raise ModelError(f"{self.spec} was exported for {self.encoders.meta['pixels']} model input, got "
                             f"{list(pixels.shape[1:])}: pass square renders", field="model")
        with torch.autocast(self.device.type, dtype=self.amp_dtype, enabled=amp and self.autocast):
            return self._image_features(pixels)

    def _forward_only(self, call: Callable[[runtime_mod.Encoders], Tensor | None], no_grad: bool) -> Tensor | None:
        """``call(encoders)`` when this call may use ONNX Runtime, else None (use torch).

        ``no_grad``: nothing can be differentiated. A differentiable guide uses ONNX Runtime only when
        gradients are disabled altogether (the agreed contract); a forward-only guide has no choice.
        """
        if self.encoders is None:
            return None
        if self.model is not None and torch.is_grad_enabled():
            return None
        if self.model is None and not no_grad:
            raise ModelError(f"{self.spec} is forward only (ONNX Runtime): it gives no gradients; use an hf: "
                             "or random: model, or selection only", field="model")
        try:
            return call(self.encoders)
        except Exception as exc:  # onnxruntime raises its own types
            if self.model is None:
                raise ModelError(f"ONNX Runtime failed on {self.spec}: {exc}", field="model") from exc
            self._runtime_failed(self.runtime, exc)
            return None

    def _runtime_failed(self, runtime: str, exc: Exception) -> None:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        log.warning("ONNX Runtime (%s) unavailable for %s, using torch: %s: %s", runtime, self.spec,
                    type(exc).__name__, first[:300])
        self.encoders, self.runtime = None, "torch"


def load_guide(
    spec: str,
    *,
    device: str = "cpu",
    autocast: bool = True,
    offline: bool | None = None,
    cache_dir: str | None = None,
    runtime: str = "torch",
    threads: int | None = None,
) -> Guide:
    """Build the guide named by ``spec`` (see module docstring); raises ``ModelError`` if it cannot.

    ``offline=None`` follows the environment (see ``downloads_allowed``); ``cache_dir`` overrides the
    Hugging Face cache directory. ``runtime`` chooses where forward-only calls run (``use_runtime``);
    ``threads`` is ONNX Runtime's intra-op threads (None: torch's current thread count).
    """
    backend, rest = backends.parse(spec)
    if runtime not in runtime_mod.RUNTIMES:
        raise ModelError(f"unknown runtime {runtime!r}; choose one of {', '.join(runtime_mod.RUNTIMES)}",
                         field="runtime")
    dev = torch.device(device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ModelError(f"device {device!r} requested but this torch build sees no CUDA device", field="device")
    if offline is None:
        offline = not downloads_allowed()
    request = LoadRequest(dev, autocast, offline, cache_dir, runtime, threads or torch.get_num_threads())
    guide = backend.load_function()(spec, rest, request)
    guide.use_runtime(runtime, request.threads)
    return guide


_CACHE: dict[tuple, Guide] = {}
_CACHE_LOCK = threading.Lock()


def get_guide(spec: str, *, device: str = "cpu", autocast: bool = True, runtime: str = "torch",
              threads: int | None = None) -> Guide:
    """Process-wide cache over ``load_guide``: a worker loads each model once, then reuses it.

    The lock makes concurrent first calls load once; failures are not cached, so a fixed
    environment (weights copied in) takes effect on the next call.
    """
    threads = threads or torch.get_num_threads()
    key = (spec, str(torch.device(device)), bool(autocast), runtime, threads)
    with _CACHE_LOCK:
        if key not in _CACHE:
            _CACHE[key] = load_guide(spec, device=device, autocast=autocast, runtime=runtime, threads=threads)
        return _CACHE[key]


def guide_for(config) -> Guide:
    """The guide an ``AlignConfig`` asks for (model, device, precision, runtime, threads), process-cached."""
    return get_guide(config.model, device=config.device, autocast=config.autocast, runtime=config.runtime,
                     threads=config.threads)


def byte_tokenize(texts: list[str], vocab_size: int, context: int = TEXT_CONTEXT) -> dict[str, Tensor]:
    """Deterministic in-code tokenizer for ``random:`` models: UTF-8 bytes are the token ids.

    Random weights ship no tokenizer file and none may be downloaded; any injective text -> ids map
    serves. SOT = vocab_size - 2, EOT = vocab_size - 1 (CLIP's layout; the text model pools at the
    first EOT), padded with EOT, truncated to ``context`` tokens.
    """
    sot, eot = vocab_size - 2, vocab_size - 1
    ids = torch.full((len(texts), context), eot, dtype=torch.long)
    mask = torch.zeros((len(texts), context), dtype=torch.long)
    for i, text in enumerate(texts):
        row = [sot, *text.encode("utf-8")[: context - 2], eot]
        ids[i, : len(row)] = torch.tensor(row)
        mask[i, : len(row)] = 1
    return {"input_ids": ids, "attention_mask": mask}


def _pooled(output) -> Tensor:
    """transformers < 5 returns the embedding tensor, 5.x an output object with it in ``pooler_output``."""
    return output if isinstance(output, Tensor) else output.pooler_output


def _load_random(spec: str, arch: str, request: LoadRequest) -> Guide:
    if arch not in RANDOM_ARCHS:
        raise ModelSpecError(f"unknown random architecture {arch!r}; choose one of {', '.join(RANDOM_ARCHS)}",
                         field="model")
    from transformers import CLIPConfig, CLIPModel

    device = request.device
    shape = RANDOM_ARCHS[arch]
    vocab = shape["text"]["vocab_size"]
    text = {**shape["text"], "max_position_embeddings": TEXT_CONTEXT, "bos_token_id": vocab - 2,
            "eos_token_id": vocab - 1, "pad_token_id": vocab - 1}
    config = CLIPConfig(text_config=text, vision_config=shape["vision"], projection_dim=shape["projection_dim"])
    with torch.random.fork_rng(devices=[]):  # seeded weights without disturbing the caller's RNG
        torch.manual_seed(RANDOM_SEED)
        model = CLIPModel(config).float()
    model.to(device)

    return Guide(spec, model, image_features=lambda x: _pooled(model.get_image_features(pixel_values=x)),
                 tokenize=lambda texts: byte_tokenize(texts, vocab),
                 text_features=lambda batch: _pooled(model.get_text_features(**_on(batch, device))),
                 save_tokenizer=lambda directory: {"kind": "bytes", "vocab_size": vocab},
                 transform=ImageTransform.clip(shape["vision"]["image_size"]),
                 embed_dim=shape["projection_dim"], device=device, autocast=request.autocast)


def _on(batch: Tokens, device: torch.device) -> Tokens:
    return {k: v.to(device) for k, v in batch.items()}


def _hf_tokenize(tokenizer, siglip: bool, context: int) -> Callable[[list[str]], Tokens]:
    """SigLIP was trained on max-length padded text without a mask; CLIP/ALIGN pad to the longest."""
    def tokenize(texts: list[str]) -> Tokens:
        batch = tokenizer(texts, padding="max_length" if siglip else True, truncation=True, max_length=context,
                          return_tensors="pt")
        return {k: v for k, v in batch.items() if isinstance(v, Tensor)}

    return tokenize


def _load_hf(spec: str, name: str, request: LoadRequest) -> Guide:
    import transformers

    device, offline, cache_dir = request.device, request.offline, request.cache_dir
    path = Path(name).expanduser()
    local = looks_local(name)
    if local and not (path / "config.json").is_file():
        raise ModelError(f"no transformers model directory at {path} (expected config.json from "
                         "save_pretrained)", field="model")
    source = str(path) if local else name
    kwargs = {"cache_dir": cache_dir, "local_files_only": offline}
    try:
        model = transformers.AutoModel.from_pretrained(source, **kwargs).float()
        tokenizer = transformers.AutoTokenizer.from_pretrained(source, **kwargs)
        processor_cfg = _processor_config(source, kwargs)
    except (OSError, ValueError, ImportError) as exc:
        raise ModelError(_missing_weights_message(name, offline, cache_dir, exc), field="model") from exc
    if not (hasattr(model, "get_image_features") and hasattr(model, "get_text_features")):
        raise ModelError(f"{name} is a {type(model).__name__}, not a dual image/text encoder "
                         "(CLIPModel, SiglipModel, AlignModel)", field="model")
    model.to(device)
    config = model.config
    siglip = config.model_type.startswith("siglip")
    context = config.text_config.max_position_embeddings
    if processor_cfg is not None:
        transform = ImageTransform.from_processor_config(processor_cfg)
    elif siglip:
        size = config.vision_config.image_size
        transform = ImageTransform(("size", (size, size)), None, (0.5,) * 3, (0.5,) * 3)
    else:
        transform = ImageTransform.clip(config.vision_config.image_size)

    def save_tokenizer(directory: Path) -> dict:
        tokenizer.save_pretrained(directory / "tokenizer")
        return {"kind": "hf", "siglip": siglip, "context": context}

    embed_dim = getattr(config, "projection_dim", None) or config.text_config.hidden_size
    return Guide(spec, model, image_features=lambda x: _pooled(model.get_image_features(pixel_values=x)),
                 tokenize=_hf_tokenize(tokenizer, siglip, context),
                 text_features=lambda batch: _pooled(model.get_text_features(**_on(batch, device))),
                 save_tokenizer=save_tokenizer, transform=transform, embed_dim=int(embed_dim), device=device,
                 autocast=request.autocast)


def _load_onnx(spec: str, name: str, request: LoadRequest) -> Guide:
    """An exported directory (``runtime``) as a forward-only guide: ONNX Runtime, no torch weights."""
    directory = Path(name).expanduser()
    if not (directory / runtime_mod.META).is_file():
        raise ModelError(f"no exported model at {directory} (expected {runtime_mod.META}; the ONNX cache "
                         f"under {runtime_mod.cache_root()} holds one directory per exported model)", field="model")
    if request.device.type != "cpu":
        raise ModelError(f"{spec} runs in ONNX Runtime on the CPU; use device cpu", field="device")
    if request.runtime == "torch":
        raise ModelError(f"{spec} has no torch weights; use runtime onnx, onnx-int8 or auto", field="runtime")
    meta = json.loads((directory / runtime_mod.META).read_text())
    tok = meta.get("tokenizer") or {}
    if tok.get("kind") == "bytes":
        tokenize = lambda texts: byte_tokenize(texts, tok["vocab_size"])  # noqa: E731
    elif tok.get("kind") == "hf":
        import transformers

        tokenizer = transformers.AutoTokenizer.from_pretrained(directory / "tokenizer", local_files_only=True)
        tokenize = _hf_tokenize(tokenizer, tok["siglip"], tok["context"])
    else:
        raise ModelError(f"{directory} was exported without a tokenizer ctp can rebuild", field="model")
    t = meta["transform"]
    resize = (t["resize"][0], t["resize"][1] if isinstance(t["resize"][1], int) else tuple(t["resize"][1]))
    transform = ImageTransform(resize, tuple(t["crop"]) if t["crop"] else None, tuple(t["mean"]), tuple(t["std"]))
    try:
        encoders = runtime_mod.Encoders.load(directory, int8=request.runtime == "onnx-int8", threads=request.threads)
    except Exception as exc:  # onnxruntime raises its own types
        raise ModelError(f"ONNX Runtime could not load {directory}: {exc}", field="model") from exc
    return Guide(spec, None, image_features=None, tokenize=tokenize, text_features=None, transform=transform,
                 embed_dim=int(meta["embed_dim"]), device=request.device, autocast=False, encoders=encoders)


def _processor_config(source: str, kwargs: dict) -> dict | None:
    """The image processor settings saved with a checkpoint, or None when it has none."""
    from transformers.utils import cached_file

    for filename, key in (("preprocessor_config.json", None), ("processor_config.json", "image_processor")):
        found = cached_file(source, filename, _raise_exceptions_for_missing_entries=False,
                            _raise_exceptions_for_connection_errors=False, **kwargs)
        if found:
            cfg = json.loads(Path(found).read_text())
            cfg = cfg.get(key) if key else cfg
            if cfg:
                return cfg
    return None


def _missing_weights_message(name: str, offline: bool, cache_dir: str | None, exc: Exception) -> str:
    if not offline:
        return f"could not load {name!r}: {exc}"
    # Offline, transformers' own text ("couldn't connect to ...") would contradict "downloads are off".
    absent = missing(f"hf:{name}", cache_dir=cache_dir, offline=True)
    if absent is None:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return f"could not load {name!r} from its local files: {first}"
    return absent


def _load_open_clip(spec: str, rest: str, request: LoadRequest) -> Guide:
    device, offline, cache_dir = request.device, request.offline, request.cache_dir
    arch, sep, tag = rest.partition(":")
    if not (arch and sep and tag):
        raise ModelSpecError(f"open_clip spec {spec!r} must be open_clip:ARCH:TAG, e.g. open_clip:ViT-B-32:openai",
                         field="model")
    try:
        import open_clip
    except ImportError:
        hf = OPEN_CLIP_TO_HF.get((arch, tag))
        hint = (f"use the same weights through transformers: hf:{hf}" if hf else
                "use an hf: spec naming the transformers copy of these weights (e.g. "
                "open_clip:ViT-B-32:openai is hf:openai/clip-vit-base-patch32)")
        raise ModelError(f"{spec!r} needs the open_clip package, which is not installed (it requires "
                         f"torchvision, which does not install beside this CPU torch build); {hint}",
                         field="model") from None
    absent = missing(spec, cache_dir=cache_dir, offline=offline)
    if absent:
        raise ModelError(absent, field="model")
    try:
        model = open_clip.create_model(arch, pretrained=tag, cache_dir=cache_dir, device=device)
        tokenizer = open_clip.get_tokenizer(arch)
    except (RuntimeError, OSError, ValueError) as exc:
        raise ModelError(f"open_clip could not load {arch} with {tag!r}: {exc}", field="model") from exc
    size = model.visual.image_size
    size = size if isinstance(size, int) else int(size[0])
    mean = getattr(model.visual, "image_mean", None) or CLIP_MEAN
    std = getattr(model.visual, "image_std", None) or CLIP_STD
    with torch.no_grad():
        embed_dim = int(model.encode_text(tokenizer(["a"]).to(device)).shape[-1])
    return Guide(spec, model, image_features=model.encode_image, tokenize=lambda texts: {"text": tokenizer(texts)},
                 text_features=lambda batch: model.encode_text(batch["text"].to(device)),
                 transform=ImageTransform.clip(size, mean, std), embed_dim=embed_dim, device=device,
                 autocast=request.autocast)
