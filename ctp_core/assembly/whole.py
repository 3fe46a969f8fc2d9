"""The scene judged as a whole: each step's relation judged again once later objects are placed.

A step is judged when it is placed, against the scene so far; a later object can break it (a stool pushed off
the workbench's left by paint tins, a lamp sunk into a chair placed after it). ``verdict`` judges one step's
relation on a scene (``adjust.adjust``: the step's figure where it is, the other objects it is given its target
(``assemble`` gives the base, the grounds and those near it), the step's grounds and reading, as the run judged
it) and says whether the figure intersects another object (the search's ``sunk`` past ``ordering.SUNK``, where its
relation does not go into the ground). ``assemble`` judges with it what a new object breaks of the steps before it
(and then tries the new step's alternatives) and the final scene (the report's ``whole``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

from ctp_core import adjust
from ctp_core.assembly import sinking
from ctp_core.reading import records
from ctp_core.reading.relation import RelationReading
from ctp_core.search.ordering import SUNK

if TYPE_CHECKING:
    from ctp_core.align import AlignResult

__all__ = ["said", "verdict"]


def verdict(others: trimesh.Scene, name: str, mesh: trimesh.Trimesh, to_scene: np.ndarray, result: AlignResult,
            grounds: Sequence[str], *, placed: Sequence[tuple[str, trimesh.Trimesh, np.ndarray]] = (),
            floor: float | None = None, reading: RelationReading | None = None) -> dict[str, Any]:
    """The relation of the step that placed ``mesh`` (its run ``result``, its ``grounds``) judged where it is now
    (``to_scene``: its file frame -> scene) against every ``other`` object: name, relation, on, holds, stable,
    penetration (the search's), how deep it is measured into the others and below the floor (``sinking``:
    ``penetration_mm``, ``into``, ``below_floor_mm``), intersects. ``placed``: the other objects as (name, mesh in
    its own file frame, its 4x4 into the scene), for the measure; ``floor``: the scene's (the base's bottom);
    ``reading``: the relation to judge (a relation said of the object besides its own), else the run's."""
    reading = reading or RelationReading.from_verdict(result.relation)
    # the scene's up and front found as the step's run found them, from its objects (their files' frames)
    done = adjust.adjust(others, mesh, to_scene, result.config, on=list(grounds), reading=reading)
    judged = done.relation or {}
    into = reading is not None and any(records.RELATIONS[p].penetration != "no" for p in reading.relations
                                       if p in records.RELATIONS)
    # a relation that goes into its ground ("in", "through") is not sunk for being there; into the others it is
    sink = sinking.sinking(name, mesh, to_scene, placed, floor, skip=list(grounds) if into else ())
    matrix = np.asarray(to_scene, dtype=np.float64)
    diagonal = float(np.linalg.norm(mesh.extents)) * float(np.cbrt(abs(np.linalg.det(matrix[:3, :3]))))
    return {"name": name, "relation": judged.get("name"), "on": list(grounds), "holds": judged.get("holds"),
            "stable": judged.get("stable"), "penetration": done.penetration, **sink.to_dict(),
            "intersects": (not into and done.penetration > SUNK) or sink.sunk(diagonal)}


def said(judged: dict[str, Any]) -> str:
    """A verdict that fails, in words ("stool left workbench: no longer holds", "cushion on sofa: sinks 43.0 mm
    into sofa")."""
    if not judged["intersects"]:
        what = "no longer holds"
    elif judged.get("below_floor_mm", 0.0) > judged.get("penetration_mm", 0.0):
        what = f"is {judged['below_floor_mm']} mm below the floor"
    elif judged.get("into"):
        what = f"sinks {judged['penetration_mm']} mm into {judged['into']}"
    else:
        what = "intersects another object"
    return f"{judged['name']} {judged['relation']} {' and '.join(judged['on'])}: {what}"
