"""The scene judged as a whole: each step's relation judged again once later objects are placed.

A step is judged when it is placed, against the scene so far; a later object can break it (a stool pushed off
the workbench's left by paint tins, a lamp sunk into a chair placed after it). ``verdict`` judges one step's
relation on a scene (``adjust.adjust``: the step's figure where it is, every other object its target, the step's
grounds and reading, as the run judged it) and says whether the figure intersects another object (the search's
``sunk`` past ``ordering.SUNK``, where its relation does not go into the ground). ``assemble`` judges with it what
a new object breaks of the steps before it (and then tries the new step's alternatives) and the final scene (the
report's ``whole``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import trimesh

from ctp_core import adjust
from ctp_core.reading import records
from ctp_core.reading.relation import RelationReading
from ctp_core.search.ordering import SUNK

if TYPE_CHECKING:
    from ctp_core.align import AlignResult

__all__ = ["said", "verdict"]


def verdict(others: trimesh.Scene, name: str, mesh: trimesh.Trimesh, to_scene: np.ndarray, result: AlignResult,
            grounds: Sequence[str]) -> dict[str, Any]:
    """The relation of the step that placed ``mesh`` (its run ``result``, its ``grounds``) judged where it is now
    (``to_scene``: its file frame -> scene) against every ``other`` object: name, relation, on, holds, stable,
    penetration, intersects."""
    reading = RelationReading.from_verdict(result.relation)
    # the scene's up and front found as the step's run found them, from its objects (their files' frames)
    done = adjust.adjust(others, mesh, to_scene, result.config, on=list(grounds), reading=reading)
    judged = done.relation or {}
    into = reading is not None and any(records.RELATIONS[p].penetration != "no" for p in reading.relations
                                       if p in records.RELATIONS)
    return {"name": name, "relation": judged.get("name"), "on": list(grounds), "holds": judged.get("holds"),
            "stable": judged.get("stable"), "penetration": done.penetration,
            "intersects": not into and done.penetration > SUNK}


def said(judged: dict[str, Any]) -> str:
    """A verdict that fails, in words ("stool left workbench: no longer holds")."""
    what = "intersects another object" if judged["intersects"] else "no longer holds"
    return f"{judged['name']} {judged['relation']} {' and '.join(judged['on'])}: {what}"
