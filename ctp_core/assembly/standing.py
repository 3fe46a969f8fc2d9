"""What each object of a scene stands on, measured on the scene as it is: the object whose level surface is
right under its bottom, else the floor. A person reads it beside each relation ("the mug: on the table, stands on
the table"; "the stool: left of the bench, stands on the floor"); it is measured, not read from the sentence, so a
scene adjusted by hand says where its objects stand now.

Frames: the scene frame (``assemble``: the base's file frame), +Y up, as the scene's judge (``whole``) reads the
floor. Rays are cast down from an object's lowest points (those within ``BAND`` of its height above its bottom)
and its footprint's centre, from ``START`` of its height above them (an object sunk a little into what it stands
on still finds it); a hit on a level face (``LEVEL``) of another object no lower than ``REACH`` of its height under
its bottom is what it stands on (the highest such surface).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from ctp_core.pairs import bottom_points, level_hits

if TYPE_CHECKING:
    from ctp_core.assembly.assemble import Placed

__all__ = ["FLOOR", "stands_on"]

FLOOR = "floor"
BAND = 0.02  # of an object's height: its bottom
START = 0.5  # of an object's height above its bottom: where rays start (inside it, so one sunk a little still hits)
REACH = 0.05  # of an object's height: a surface this far under its bottom still carries it (a gap the search left)
RAYS = 16  # lowest vertices a ray is cast down from, besides the footprint's centre
LEVEL = 0.7  # |normal . up| of a face a thing can stand on (a wall grazed on the way down is not one)
UP = np.array([0.0, 1.0, 0.0])


def stands_on(objects: Sequence[Placed]) -> dict[str, str]:
    """Each object's name -> the name of the object it stands on, or ``FLOOR`` (the base always: it is the
    scene's frame and stands on the floor)."""
    meshes = {p.name: p.mesh.copy().apply_transform(np.asarray(p.to_scene.matrix, dtype=np.float64))
              for p in objects}
    return {p.name: FLOOR if i == 0 else _under(meshes[p.name], {n: m for n, m in meshes.items() if n != p.name})
            for i, p in enumerate(objects)}


def _under(mesh: trimesh.Trimesh, others: dict[str, trimesh.Trimesh]) -> str:
    """The other object whose level surface is highest right under ``mesh``'s bottom (scene frame), else FLOOR."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    height = vertices @ UP
    span = float(np.ptp(height)) or 1e-9
    bottom = float(height.min())
    origins = bottom_points(vertices, UP, BAND * span, RAYS) + START * span * UP
    best, best_level = FLOOR, -np.inf
    for name, other in others.items():
        heights = level_hits(other, origins, UP, LEVEL) @ UP
        heights = heights[heights >= bottom - REACH * span]
        if len(heights) and float(heights.max()) > best_level:
            best, best_level = name, float(heights.max())
    return best
