"""What a run hands back: the arranged scene as GLB, a JSON report, and a preview contact sheet.

All transforms here are in *file frames*: the target is written untouched and the source keeps its
own vertices under a node whose matrix is ``result.source_to_target`` (source file -> target file),
so a viewer or a DCC tool shows the arrangement and the transform stays editable.
"""

from __future__ import annotations

import datetime as dt
import io
import json
import math
import platform
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
import trimesh
from PIL import Image

import ctp_core
from ctp_core.frames import SOURCE_FILE, TARGET_FILE
from ctp_core.pose import matrix_to_quaternion

if TYPE_CHECKING:  # align imports the whole engine; exporting a result needs none of it
    from ctp_core.align import AlignResult


def scene_glb(result: AlignResult) -> bytes:
    """One GLB with two named nodes, "target" (identity) and "source" (placed), with their materials."""
    scene = trimesh.Scene()
    scene.add_geometry(result.target, node_name="target", geom_name="target")
    scene.add_geometry(result.source, node_name="source", geom_name="source",
                       transform=np.asarray(result.source_to_target, dtype=np.float64))
    return trimesh.exchange.gltf.export_glb(scene)


def report(result: AlignResult) -> dict:
    """A JSON-serialisable record of the run: the answer (4x4 and t / q wxyz / s), inputs and provenance."""
    config = result.config
    return {
        "transform": {
            "from_frame": SOURCE_FILE,
            "to_frame": TARGET_FILE,
            "matrix": np.asarray(result.source_to_target, dtype=float).tolist(),
            "translation": result.translation.tolist(),
            "rotation_wxyz": matrix_to_quaternion(result.rotation).tolist(),
            "scale": result.scale,
        },
        "objective": _jsonable(result.objective),
        "prompt": result.prompt,
        "model": result.extra.get("model", config.model),
        "seed": config.seed,
        "preset": config.preset,
        "config": config.model_dump(mode="json"),
        "hparams": _jsonable(result.hparams),
        "restarts": _jsonable(result.restarts),
        "timings": _jsonable(result.timings),
        "extra": _jsonable({k: v for k, v in result.extra.items() if k != "model"}),
        "versions": {
            "ctp": _version("ctp", ctp_core.__version__),
            "torch": torch.__version__,
            "trimesh": trimesh.__version__,
            "numpy": np.__version__,
            "python": platform.python_version(),
        },
        "created_at": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
    }


def preview_png(images: np.ndarray) -> bytes:
    """(V, H, W, 3) uint8 views -> one PNG contact sheet, near-square grid (2x2 for 4), white gaps."""
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8 or len(images) == 0:
        raise ValueError(f"expected (V, H, W, 3) uint8 views, got {images.shape} {images.dtype}")
    count, height, width, _ = images.shape
    cols = math.ceil(math.sqrt(count))
    rows = math.ceil(count / cols)
    sheet = np.full((rows * height, cols * width, 3), 255, dtype=np.uint8)
    for i, view in enumerate(images):
        r, c = divmod(i, cols)
        sheet[r * height:(r + 1) * height, c * width:(c + 1) * width] = view
    buffer = io.BytesIO()
    Image.fromarray(sheet).save(buffer, format="PNG")
    return buffer.getvalue()


def write_outputs(result: AlignResult, *, glb: Path | None, report_path: Path | None,
                  preview: Path | None) -> None:
    """Write whichever outputs have a path; a preview needs ``result.preview``."""
    if preview is not None and result.preview is None:
        raise ValueError("a preview was requested but the result holds no preview images")
    outputs = [
        (glb, lambda: scene_glb(result)),
        (report_path, lambda: (json.dumps(report(result), indent=2) + "\n").encode()),
        (preview, lambda: preview_png(result.preview)),
    ]
    for path, make in outputs:
        if path is not None:
            path = Path(path)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(make())


def _version(package: str, fallback: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return fallback


def _jsonable(value):
    """numpy arrays/scalars and tuples -> plain JSON types, recursively; anything else -> its str."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray | torch.Tensor):
        return _jsonable(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is None or isinstance(value, str | int | float | bool):
        return value
    return str(value)
