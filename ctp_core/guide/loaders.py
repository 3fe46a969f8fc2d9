"""Loading a guide: a model spec -> a loaded ``guidance.Guide`` (``load_guide``, process-cached by ``get_guide``).

``LOADERS`` names one loader per ``backends.BACKENDS`` prefix (``load_hf``, ``load_open_clip``, ``load_random``,
``load_onnx``); each takes ``(spec, rest_of_spec, guidance.LoadRequest)``. Kept apart from ``guidance`` so the
Guide's own module says what a guide does, and this one how each backend builds one; ``guidance`` sits below this
module and never imports it (no import cycle).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from pathlib import Path

import torch
from torch import Tensor

from ctp_core.config import backends
from ctp_core.errors import ModelError, ModelSpecError
from ctp_core.guide import runtime as runtime_mod
from ctp_core.guide.checkpoints import downloads_allowed, looks_local, missing
from ctp_core.guide.guidance import (
    CLIP_MEAN,
    CLIP_STD,
    TEXT_CONTEXT,
    Guide,
    ImageTransform,
    LoadRequest,
    Tokens,
    byte_tokenize,
)


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


def _pooled(output) -> Tensor:
    """transformers < 5 returns the embedding tensor, 5.x an output object with it in ``pooler_output``."""
    return output if isinstance(output, Tensor) else output.pooler_output


def load_random(spec: str, arch: str, request: LoadRequest) -> Guide:
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


def load_hf(spec: str, name: str, request: LoadRequest) -> Guide:
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


def load_onnx(spec: str, name: str, request: LoadRequest) -> Guide:
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


def load_open_clip(spec: str, rest: str, request: LoadRequest) -> Guide:
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


# One loader per ``backends.BACKENDS`` prefix: ``backends`` stays free of torch (the API validates specs with it),
# so the prefix -> loader map lives here, beside the loaders it names.
LOADERS: dict[str, Callable[[str, str, LoadRequest], Guide]] = {
    "hf": load_hf, "open_clip": load_open_clip, "random": load_random, "onnx": load_onnx}


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
    """Build the guide named by ``spec`` (see ``guidance``'s docstring); raises ``ModelError`` if it cannot.

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
    guide = LOADERS[backend.prefix](spec, rest, request)
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
