"""What a run hands back: the arranged scene as GLB, a JSON report, and a preview contact sheet.

All transforms here are in *file frames*: the target is written untouched and the source keeps its
own vertices under a node whose matrix is ``result.source_to_target`` (source file -> target file),
so a viewer or a DCC tool shows the arrangement and the transform stays editable. An assembly
(``assemble``) writes every object as its own named node under its source file -> scene matrix, and
its report lists every stage; several copies (``copies``) write one node per copy (``<source>_1`` ...), and
their report lists each copy's transform and verdict and the set's measures.
"""

from __future__ import annotations

import datetime as dt
import io
import json
import math
import platform
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
import trimesh
from PIL import Image

import ctp_core
from ctp_core import orientation, priors
from ctp_core.assembly import standing
from ctp_core.assembly.assemble import Assembly, Placed
from ctp_core.assembly.copies import Copies
from ctp_core.geometry.frames import SCENE, SOURCE_FILE, TARGET_FILE, Similarity
from ctp_core.geometry.pose import matrix_to_quaternion
from ctp_core.orientation import canonical
from ctp_core.pairs import objects

if TYPE_CHECKING:  # align imports the whole engine; exporting a result needs none of it
    from ctp_core.adjust import Adjusted
    from ctp_core.align import AlignResult
    from ctp_core.assembly.adjusted import SceneAdjusted


def scene_glb(result: AlignResult, source_name: str | None = None, target_name: str | None = None) -> bytes:
    """One GLB with named nodes and their materials: the target (identity) and the source (placed), named as
    given here, else by the names the run's priors read (``result.priors``)."""
    return arrangement_glb(result.target, result.source, result.source_to_target,
                           source_name or result.priors.get("source_name") or "source",
                           target_name or result.priors.get("target_name"))


def arrangement_glb(target: trimesh.Trimesh | trimesh.Scene, source: trimesh.Trimesh, source_to_target: np.ndarray,
                    source_name: str = "source", target_name: str | None = None) -> bytes:
    """A target (file frame, untouched) and the source under its source file -> target file matrix, as one GLB.

    A scene target (the objects placed so far) keeps one node per object under its own name; a single mesh
    target's node is ``target_name`` (unset: the mesh's own name, ``pairs.objects``). The source's node is named
    ``source_name``, made unique among them, and is the last node (``adjust`` reads it back so).
    """
    scene = trimesh.Scene()
    placed = [(target_name, target)] if isinstance(target, trimesh.Trimesh) and target_name else objects(target)
    names = [name for name, _ in placed]
    for name, mesh in placed:
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    source_name = next(n for n in (source_name, *(f"{source_name}-{i}" for i in range(2, len(names) + 3)))
                       if n not in names)
    scene.add_geometry(source, node_name=source_name, geom_name=source_name,
                       transform=np.asarray(source_to_target, dtype=np.float64))
    return trimesh.exchange.gltf.export_glb(scene)


def assembly_glb(assembly: Assembly) -> bytes:
    """One GLB, every object its own named node with its materials, under its file -> scene matrix."""
    return trimesh.exchange.gltf.export_glb(assembly.scene())


def copies_glb(copies: Copies) -> bytes:
    """One GLB: the target (node named as the target) and one named node per copy, target file frame."""
    return trimesh.exchange.gltf.export_glb(copies.scene())


def copies_report(copies: Copies) -> dict:
    """The record of a run of several copies: each copy's source file -> target file transform, what it is judged
    against and its verdict, the set's measures (``copies.set_metrics``), what the prompt was read as."""
    config = copies.config
    return {
        "count": copies.count, "arrangement": copies.arrangement, "prompt": copies.prompt,
        "copy_prompt": copies.one_prompt, "reading": copies.counted.to_dict(),
        "relation": None if copies.reading is None else copies.reading.name,
        "source_is_figure": True if copies.reading is None else copies.reading.source_is_figure,
        "target_name": copies.target_name, "source_name": copies.source_name,
        "copies": [_jsonable({"name": c.name, "transform": transform(Similarity(c.source_to_target, SOURCE_FILE,
                                                                                TARGET_FILE)),
                              "on": c.on, "relation": c.relation, "how": c.how, "seconds": c.seconds,
                              "penetration": c.penetration,
                              "objective": None if c.result is None else c.result.objective})
                   for c in copies.copies],
        "metrics": _jsonable(copies.metrics),
        "guide": copies.guide, "guide_why": copies.guide_why, "seed": config.seed, "preset": config.preset,
        "config": config.model_dump(mode="json"),
        "timings": _jsonable(copies.timings),
        **_provenance(),
    }


def adjusted_copies_report(original: dict, copy: int, adjusted: Adjusted, metrics: dict, *, at: str) -> dict:
    """A copies report once a person saved copy ``copy`` (1-based) adjusted (``adjust``): that copy's transform,
    verdict and penetration are the adjusted ones (``adjusted`` true, ``original_transform`` the run's own, kept
    through later saves), ``metrics`` the set's again; ``adjusted`` true and ``adjustment`` the measures, the copy
    and when (``at``, ISO 8601)."""
    copies = list(original["copies"])
    entry = copies[copy - 1]
    copies[copy - 1] = {**entry, "transform": transform(adjusted.transform), "relation": _jsonable(adjusted.relation),
                        "penetration": adjusted.penetration, "adjusted": True,
                        "original_transform": entry.get("original_transform", entry["transform"])}
    return {**original, "copies": copies, "metrics": _jsonable(metrics), "adjusted": True,
            "adjustment": {**_jsonable(adjusted.to_dict()), "copy": copy, "saved_at": at}}


def transform(similarity: Similarity) -> dict:
    """A named similarity as the report writes it: frames, 4x4, translation, rotation (wxyz), scale."""
    return {
        "from_frame": similarity.from_frame,
        "to_frame": similarity.to_frame,
        "matrix": np.asarray(similarity.matrix, dtype=float).tolist(),
        "translation": similarity.translation.tolist(),
        "rotation_wxyz": matrix_to_quaternion(similarity.rotation).tolist(),
        "scale": similarity.scale,
    }


def report(result: AlignResult) -> dict:
    """A JSON-serialisable record of the run: the answer (4x4 and t / q wxyz / s), inputs and provenance."""
    return {**_run(result), **_provenance()}


def assembly_report(assembly: Assembly) -> dict:
    """The record of an assembly: every object's file -> scene transform, each stage's run (``keeps_up``: whether
    its source kept its own up and why; ``kept``: what keeping its answer took, ``StepResult.kept``), every
    relation judged on the final scene (``whole``)."""
    first = assembly.results[0].result.config
    return {
        "frame": SCENE,
        "objects": placed_objects(assembly.objects, standing.stands_on(assembly.objects)),
        "stages": [{"stage": s.index, "of": s.count, "name": s.step.name, "on": s.on,
                    "grounds": s.grounds or [s.on], "image_guided": s.step.image is not None,
                    "also": [a.to_dict() for a in s.step.also],
                    **_run(s.result, transform(assembly.objects[s.index].to_scene)),
                    **({"keeps_up": s.result.keeps_up} if s.result.keeps_up else {}),
                    **({"kept": s.kept} if s.kept else {})} for s in assembly.results],
        "whole": _jsonable(assembly.whole),
        "model": first.model, "seed": first.seed, "preset": first.preset,
        "timings": _jsonable(assembly.timings),
        **_provenance(),
    }


def placed_objects(objects: Sequence[Placed], stands_on: dict[str, str]) -> list[dict]:
    """The report's ``objects``: each one's name, file -> scene transform and what it stands on
    (``standing.stands_on``: an object's name, or floor)."""
    return [{"name": p.name, "transform": transform(p.to_scene), "stands_on": stands_on[p.name]} for p in objects]


def adjusted_scene_report(original: dict, done: SceneAdjusted, *, at: str) -> dict:
    """An assembly's report once a person saved one object adjusted by hand (``assembly.adjusted``): the objects
    where they are now, that object's stage transform, every relation judged again (``whole``), ``adjusted`` true
    and ``adjustment`` its measures, which object, when (``at``, ISO 8601) and every object's placement as the run
    left it (``original_objects``, kept through later saves). Each stage's run record (objective, relation at its
    placing) still describes the run."""
    first = original.get("adjustment", {}).get("original_objects", original["objects"])
    objects = placed_objects(done.objects, done.stands_on)
    moved = next(o for o in objects if o["name"] == done.name)
    stages = [{**s, "transform": moved["transform"]} if s["name"] == done.name else s for s in original["stages"]]
    return {**original, "objects": objects, "stages": stages, "whole": _jsonable(done.whole), "adjusted": True,
            "adjustment": {**_jsonable(done.adjusted.to_dict()), "object": done.name, "saved_at": at,
                           "original_objects": first}}


def adjusted_report(original: dict, adjusted: Adjusted, *, at: str) -> dict:
    """A job's report once a person saved an adjusted placement (``adjust``): ``transform`` is the adjusted one,
    ``adjusted`` true and ``adjustment`` its measures, when (``at``, ISO 8601) and the run's own answer
    (``original_transform``, kept through later saves). The rest (objective, relation, restarts, alternatives)
    still describes the run's answer."""
    first = original.get("adjustment", {}).get("original_transform", original["transform"])
    return {**original, "transform": transform(adjusted.transform), "adjusted": True,
            "adjustment": {**_jsonable(adjusted.to_dict()), "saved_at": at, "original_transform": first}}


def _run(result: AlignResult, answer: dict | None = None) -> dict:
    config = result.config
    return {
        "transform": answer or transform(result.transform),
        "objective": _jsonable(result.objective),
        "prompt": result.prompt,
        "model": result.model,
        "guide": result.guide,  # the guide chosen for the run (a model spec or "none") and why (``guide.selection``)
        "guide_why": result.guide_why,
        "seed": config.seed,
        "preset": config.preset,
        "config": config.model_dump(mode="json"),
        "hparams": _jsonable(priors.to_report(result.priors)),
        "relation": _jsonable(result.relation),  # predicates.RelationVerdict of the answer; None without one
        "contact": _jsonable(result.contact),  # align.contact_of: the answer's gap to the target, touching or not
        "guide_say": _jsonable(result.guide_say),  # ordering.GuideSay: the guide's say and who chose; None: no guide
        "restarts": _jsonable(result.restarts),
        # the best distinct placements, the answer first (an assembly's stages: none, their frames differ)
        "alternatives": [] if answer is not None else [
            _jsonable({**{k: v for k, v in a.items() if k != "source_to_target"},
                       "transform": transform(result.alternative(k).transform)})
            for k, a in enumerate(result.alternatives)],
        "timings": _jsonable(result.timings),
        "extra": _jsonable(_extra(result)),
        "warnings": _jsonable(result.warnings),  # {"code", "message", ...}: what the run went on despite
    }


def _extra(result: AlignResult) -> dict:
    """The run's provenance fields under the report's ``extra`` key, in the order the report has always had."""
    return {
        "best_restart": result.best_restart, "on": result.on, "grounds": result.grounds,
        "guidance": result.guided_by,
        "runtime": result.runtime, "clip_images": result.clip_images, "phase_timings": result.phase_timings,
        "target_upright": _frame(result.target_upright), "source_upright": _frame(result.source_upright),
        "scale": result.scaling,  # scale mode: initial scale and where from, the ladder, the final scale
        "parts": result.ground_parts,  # the ground's named parts the usual places are on, with why
    }


def _frame(upright: canonical.Upright | None) -> dict | None:
    """One object's up and front as the run used them (file frame) and why (``orientation``)."""
    if upright is None:
        return None
    return {"rotation": upright.rotation.tolist(), "changed": upright.changed, **orientation.to_dict(upright)}


def _provenance() -> dict:
    return {
        "versions": {
            "ctp": _version("ctp", ctp_core.__version__),
            "torch": torch.__version__,
            "trimesh": trimesh.__version__,
            "numpy": np.__version__,
            "python": platform.python_version(),
        },
        "created_at": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
    }


def strip_png(images: np.ndarray) -> bytes:
    """(K, H, W, 3) uint8 views -> one PNG, side by side with no gaps (image k at x = k W: a page can show each)."""
    buffer = io.BytesIO()
    Image.fromarray(np.concatenate(list(images), axis=1)).save(buffer, format="PNG")
    return buffer.getvalue()


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


def write_outputs(result: AlignResult | Assembly | Copies, *, glb: Path | None, report_path: Path | None,
                  preview: Path | None) -> None:
    """Write whichever outputs have a path (of one run, a whole assembly or several copies); a preview needs
    ``result.preview``."""
    if preview is not None and result.preview is None:
        raise ValueError("a preview was requested but the result holds no preview images")
    make_glb, make_report = (
        (assembly_glb, assembly_report) if isinstance(result, Assembly) else
        (copies_glb, copies_report) if isinstance(result, Copies) else (scene_glb, report))
    outputs = [
        (glb, lambda: make_glb(result)),
        (report_path, lambda: (json.dumps(make_report(result), indent=2) + "\n").encode()),
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
