"""ONNX Runtime for the guide's forward-only calls: exported towers, their cache and CPU sessions.

Forward-only encoding (search scoring, selection on evaluation views, the upright judge, metrics)
needs no autograd, and ONNX Runtime is built for exactly that. ``Guide`` owns an ``Encoders`` when
its runtime is ``onnx`` or ``onnx-int8`` and routes a call to it when gradients are off; its gradient
path stays in torch.

Export: the vision tower (model input pixels -> features) and the text tower (token tensors ->
features) go through ``torch.onnx.export`` once, with a dynamic batch (and sequence) axis, into a
directory of the cache (``cache_root``) named by a hash of the model spec, a hash of its weights and
the exporter's versions (torch, onnxscript, opset, this module's ``FORMAT``). A cached directory is
loaded, never re-exported; an export writes to a temporary directory and renames it into place, so
concurrent workers never read a half-written one. ``int8`` is onnxruntime's dynamic quantisation of
the vision tower (weights int8, activations quantised per call); the text tower stays fp32 (it runs
once per job, and its embedding enters the gradient loss).

A cache directory is itself a model: ``meta.json`` says how to tokenize and preprocess, so
``onnx:DIR`` (``guidance``) loads it without torch weights, as a forward-only guide.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import get_args

import numpy as np
import torch

from ctp_core.config import Runtime

log = logging.getLogger(__name__)

RUNTIMES: tuple[str, ...] = get_args(Runtime)  # config.Runtime as a tuple
OPSET = 20
FORMAT = 1  # bump when what a cache directory holds changes
VISION, VISION_INT8, TEXT, META = "vision.onnx", "vision.int8.onnx", "text.onnx", "meta.json"


def cache_root() -> Path:
    """``CTP_ONNX_CACHE``, else ``$XDG_CACHE_HOME/ctp/onnx``, else ``~/.cache/ctp/onnx``."""
    if os.environ.get("CTP_ONNX_CACHE"):
        return Path(os.environ["CTP_ONNX_CACHE"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "ctp" / "onnx"


def resolve(runtime: str, *, device: str, bf16: bool) -> str:
    """The runtime ``auto`` stands for (measured rule, docs/guidance.md); others unchanged.

    ``auto``: torch on CUDA and on CPUs where the guide runs bf16 autocast (native bf16 beat ONNX
    Runtime fp32 there), ONNX Runtime fp32 on other CPUs (faster than torch fp32, same cosines to 1e-6).
    int8 is never chosen automatically: its error on real weights is unmeasured.
    """
    if runtime != "auto":
        return runtime
    return "torch" if device != "cpu" or bf16 else "onnx"


def weights_hash(module: torch.nn.Module) -> str:
    """A digest of the names, shapes, dtypes and values of ``module``'s parameters and buffers."""
    digest = hashlib.blake2b(digest_size=16)
    for name, tensor in sorted(module.state_dict().items()):
        t = tensor.detach().cpu().contiguous()
        digest.update(f"{name}:{tuple(t.shape)}:{t.dtype};".encode())
        digest.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return digest.hexdigest()


def cache_key(spec: str, weights: str) -> dict:
    """Everything an exported graph depends on; its hash names the cache directory."""
    import onnxscript

    return {"spec": spec, "weights": weights, "torch": torch.__version__, "onnxscript": onnxscript.__version__,
            "opset": OPSET, "format": FORMAT}


def cache_dir(key: dict) -> Path:
    slug = "".join(c if c.isalnum() or c in "-_." else "_" for c in key["spec"])[-48:]
    digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:20]
    return cache_root() / f"{slug}-{digest}"


class _Tower(torch.nn.Module):
    """A feature function as a module with positional tensor inputs, which ``torch.onnx.export`` wants."""

    def __init__(self, model: torch.nn.Module, fn: Features, names: list[str]):
        super().__init__()
        self.model = model  # registered, so the exporter sees its weights as parameters, not constants
        self.fn, self.names = fn, names

    def forward(self, *tensors: torch.Tensor) -> torch.Tensor:
        return self.fn(dict(zip(self.names, tensors, strict=True)))


Features = Callable[[dict[str, torch.Tensor]], torch.Tensor]


def _export(model: torch.nn.Module, fn: Features, inputs: dict[str, torch.Tensor],
            dynamic: dict[str, dict[int, str]], path: Path) -> None:
    """Export one tower with named dynamic axes; quiet (the exporter prints progress and warnings)."""
    names = list(inputs)
    dims = {axis: torch.export.Dim(axis, min=1, max=4096) for axes in dynamic.values() for axis in axes.values()}
    shapes = tuple({i: dims[a] for i, a in dynamic.get(n, {}).items()} or None for n in names)
    logging.getLogger("torch.onnx").setLevel(logging.ERROR)
    logging.getLogger("torch.onnx._internal.exporter._registration").setLevel(logging.ERROR)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(_Tower(model, fn, names).eval(), tuple(inputs.values()), str(path), input_names=names,
                          output_names=["features"], dynamic_shapes=(shapes,), opset_version=OPSET, dynamo=True,
                          optimize=True, external_data=False, verbose=False, report=False)


def export(directory: Path, model: torch.nn.Module, *, meta: dict,
           image_features: Callable[[torch.Tensor], torch.Tensor], text_features: Features, pixels: torch.Tensor,
           tokens: dict[str, torch.Tensor], save_tokenizer: Callable[[Path], dict] | None) -> Path:
    """Export both towers into ``directory`` unless it already holds them; returns ``directory``.

    ``pixels`` and ``tokens`` are example inputs (batch >= 2, so the batch axis stays symbolic);
    ``save_tokenizer`` writes what ``onnx:DIR`` needs to tokenize and returns its meta entry.
    """
    if (directory / META).is_file():
        return directory
    directory.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".export-", dir=directory.parent))
    tmp.chmod(0o755)  # mkdtemp makes it private; the cache may be shared by a host's workers
    try:
        _export(model, lambda d: image_features(d["pixels"]), {"pixels": pixels}, {"pixels": {0: "batch"}},
                tmp / VISION)
        _export(model, text_features, tokens, {name: {0: "batch", 1: "sequence"} for name in tokens}, tmp / TEXT)
        tokenizer = save_tokenizer(tmp) if save_tokenizer else None
        (tmp / META).write_text(json.dumps({**meta, "pixels": list(pixels.shape[1:]), "text_inputs": list(tokens),
                                            "tokenizer": tokenizer}, indent=1))
        try:
            tmp.rename(directory)
        except OSError:  # another process finished the same export first: use theirs
            if not (directory / META).is_file():
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return directory


def quantised(directory: Path) -> Path:
    """The int8 dynamic quantisation of the vision tower, made once beside the fp32 one."""
    target = directory / VISION_INT8
    if not target.is_file():
        from onnxruntime.quantization import QuantType, quantize_dynamic

        tmp = directory / f".{VISION_INT8}.{os.getpid()}"
        onnx_logger = logging.getLogger()  # quantize_dynamic warns on the root logger about pre-processing
        level = onnx_logger.level
        onnx_logger.setLevel(logging.ERROR)
        try:
            quantize_dynamic(str(directory / VISION), str(tmp), weight_type=QuantType.QInt8)
            tmp.replace(target)
        finally:
            onnx_logger.setLevel(level)
            tmp.unlink(missing_ok=True)
    return target


def session(path: Path, threads: int):
    """A CPU session: ``threads`` intra-op threads, no spinning (shared cores), full graph optimisation."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.add_session_config_entry("session.inter_op.allow_spinning", "0")
    options.log_severity_level = 3
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


@dataclass
class Encoders:
    """The two exported towers of one model as ONNX Runtime sessions; inputs and outputs are tensors."""

    directory: Path
    meta: dict
    vision: object  # onnxruntime.InferenceSession
    text: object
    int8: bool

    @classmethod
    def load(cls, directory: Path, *, int8: bool, threads: int) -> Encoders:
        meta = json.loads((directory / META).read_text())
        vision = quantised(directory) if int8 else directory / VISION
        return cls(directory, meta, session(vision, threads), session(directory / TEXT, threads), int8)

    def accepts(self, pixels: torch.Tensor) -> bool:
        """Whether ``pixels`` (N, 3, H, W) has the exported image size (the graph fixes it)."""
        return list(pixels.shape[1:]) == self.meta["pixels"]

    def image_features(self, pixels: torch.Tensor) -> torch.Tensor:
        x = np.ascontiguousarray(pixels.detach().cpu().float().numpy())
        return torch.from_numpy(self.vision.run(None, {"pixels": x})[0])

    def text_features(self, tokens: dict[str, torch.Tensor]) -> torch.Tensor:
        feed = {name: np.ascontiguousarray(tokens[name].cpu().numpy().astype(np.int64))
                for name in self.meta["text_inputs"]}
        return torch.from_numpy(self.text.run(None, feed)[0])
