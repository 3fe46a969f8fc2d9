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
- ``open_clip:ARCH:TAG``: only when ``open_clip`` is importable. It is no dependency: it imports
  torchvision, whose PyPI build does not import beside the CPU torch build. ``TAG`` may be a
  checkpoint path.
- ``random:ARCH``: the same architecture with deterministic random weights (seeded, built from a
  config in code, nothing read or downloaded) for tests and benchmarks on machines without weights.
  ``ARCH`` is one of ``loaders.RANDOM_ARCHS`` (``ViT-B-32``, ``ViT-B-16``, ``ViT-L-14``, ``tiny``).
- ``onnx:DIR``: a directory of exported towers (an entry of the ONNX cache, see ``runtime``), run by
  ONNX Runtime without torch weights. Forward only: ``Guide.differentiable`` is False, and a run that
  needs image gradients is refused when it is configured (``config``).

The backends are a registry (``backends.BACKENDS``: spec prefixes, differentiable or not); the loaders that
build a ``Guide`` for each, ``load_guide`` and its process cache ``get_guide`` are in ``loaders``.

Runtime of the forward-only calls (``runtime``: ``auto``, ``torch``, ``onnx``, ``onnx-int8``): with
``onnx``/``onnx-int8`` the guide exports its towers once (cached) and runs ``encode_images``,
``score`` and ``encode_reference_image`` in ONNX Runtime whenever gradients are disabled
(``torch.no_grad`` / ``torch.inference_mode``; ``encode_text`` always is), and in torch whenever they
are enabled, so the optimiser's gradient path is unchanged. If export or loading fails the guide logs
one line and stays on torch. ``auto`` follows ``runtime.resolve`` (measured; docs/guidance.md).

Offline by default: weights are only read from disk unless the caller passes ``offline=False`` or
the environment allows downloads (``CTP_ALLOW_DOWNLOAD=1``, or ``HF_HUB_OFFLINE=0``). Missing
weights raise ``ModelError`` at once, naming them and how to provide them; nothing waits on a network.

Precision: images go through the model under bf16 autocast on CPU and fp16 autocast on CUDA when
``autocast`` is on; text and reference images are always encoded in fp32 (once per run, so precision
costs nothing there). bf16 is on by default on CPU only where the CPU has AVX512-BF16 or AMX
(``cpu_has_fast_bf16``): there it is faster at an error far below what ranking needs, while on a CPU without
native bf16 it is emulated and many times slower than fp32, so the CPU path is fp32 there. The model's weights
are frozen (``requires_grad_(False)``) so the backward pass computes pixel gradients only. ``random:tiny`` is too
small to gain from bf16 (autocast's overhead dominates); it exists for CI. The measurements behind these rules
(``benchmarks/guidance_bench.py``) are in docs/guidance.md, "Precision and speed".
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from ctp_core.errors import ModelError
from ctp_core.guide import runtime as runtime_mod

log = logging.getLogger(__name__)

# CLIP's (OpenAI) pixel statistics; open_clip and transformers CLIP checkpoints use the same.
CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
TEXT_CONTEXT = 77  # CLIP's text context length, SOT and EOT included


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
    """What every backend loader gets besides the spec (see ``loaders.load_guide``)."""

    device: torch.device
    autocast: bool
    offline: bool
    cache_dir: str | None
    runtime: str
    threads: int


class Guide:
    """A loaded vision-language model; load once per process (``loaders.get_guide``) and reuse across jobs.

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
