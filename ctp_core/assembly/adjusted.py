"""One object of a finished scene adjusted by hand: moved (the page's handles), settled into contact when asked
(``adjust``: drop, push), and the scene judged again as a whole, every step's relation (``assemble.judged``), since
moving one object can make or break the relations of the others.

The scene is read back from a result GLB (``io.load_objects``: one node per object, base first, each mesh in the
scene frame) with its report (``export.assembly_report``: each object's file -> scene transform, each stage's
grounds and relation verdict); each step's config is the job's. The base cannot be moved: its file frame is the
scene frame. Frames: ``to_scene`` maps the object's file frame to the scene frame, as the report's ``objects``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import trimesh

from ctp_core import adjust
from ctp_core.assembly import standing
from ctp_core.assembly.assemble import Placed, Step, StepResult, judged, scene_of
from ctp_core.assembly.plan import Also
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.geometry import frames, once
from ctp_core.reading.relation import RelationReading

if TYPE_CHECKING:
    from ctp_core.align import AlignResult

__all__ = ["SceneAdjusted", "adjust_object", "read_placed"]


@dataclass(frozen=True)
class SceneAdjusted:
    """The object as adjusted and how it sits against the others (``adjust.Adjusted``), the scene's objects with
    it there, every relation judged again (the report's ``whole``) and what each object stands on."""

    name: str
    adjusted: adjust.Adjusted
    objects: list[Placed]
    whole: dict[str, Any]
    stands_on: dict[str, str]


@dataclass(frozen=True)
class _Run:
    """What judging a step reads of its run: its config and the verdict it was placed with."""

    config: AlignConfig
    relation: dict[str, Any] | None


def read_placed(scene: trimesh.Scene, report: dict[str, Any]) -> list[Placed]:
    """The scene's objects as placed (base first): each mesh back in its own file frame, under its transform."""
    objects: list[Placed] = []
    for entry in report["objects"]:
        name = entry["name"]
        if name not in scene.geometry:
            raise ConfigError(f"the result scene has no object {name!r}", field="result.glb")
        matrix = np.asarray(entry["transform"]["matrix"], dtype=np.float64)
        own = scene.geometry[name].copy().apply_transform(np.linalg.inv(matrix))
        objects.append(Placed(name, own, frames.Similarity(matrix, frames.SOURCE_FILE if objects else frames.SCENE,
                                                           frames.SCENE)))
    return objects


@once.scene()  # every step judged again asks the same of objects that have not moved
def adjust_object(scene: trimesh.Scene, report: dict[str, Any], name: str, to_scene: np.ndarray,
                  configs: Sequence[AlignConfig], *, settle: adjust.Settle = "none",
                  direction: np.ndarray | None = None) -> SceneAdjusted:
    """Put object ``name`` of the scene at ``to_scene`` (settled with ``settle`` against every other object),
    measured as ``adjust.adjust`` measures a placement against its step's grounds and reading, then judge every
    step's relation on the scene with it there. ``configs``: each step's config, in placing order."""
    objects = read_placed(scene, report)
    names = [p.name for p in objects]
    if name == names[0]:
        raise ConfigError(f"{name} is the scene's base: it stays put (its file frame is the scene's); move the "
                          "objects placed on it instead", code="invalid_object", field="object")
    if name not in names:
        raise ConfigError(f"the scene has no object {name!r}; its placed objects are {', '.join(names[1:])}",
                          code="invalid_object", field="object")
    stages = report["stages"]
    k = names.index(name)
    stage = stages[k - 1]
    upright = (stage.get("extra") or {}).get("target_upright")
    others = [p for p in objects if p.name != name]
    done = adjust.adjust(scene_of(others), objects[k].mesh, np.asarray(to_scene, dtype=np.float64), configs[k - 1],
                         settle=settle, direction=direction,
                         upright=None if upright is None else np.asarray(upright["rotation"]),
                         on=list(stage["grounds"]), reading=RelationReading.from_verdict(stage.get("relation")))
    objects[k] = replace(objects[k], to_scene=frames.Similarity(done.source_to_target, frames.SOURCE_FILE,
                                                                frames.SCENE))
    # judged reads a step's run for its config and verdict only: the stored ones stand in for the run
    results = [StepResult(i + 1, len(stages), Step(objects[i + 1].mesh, s["name"], also=[
                   Also.from_dict(a) for a in s.get("also", [])]), s["on"],
                          cast("AlignResult", _Run(configs[i], s.get("relation"))), list(s["grounds"]))
               for i, s in enumerate(stages)]
    return SceneAdjusted(name, done, objects, judged(objects, results), standing.stands_on(objects))

