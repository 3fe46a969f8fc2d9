"""How deep a placed object sinks into the others and below the floor, measured on the meshes (no search terms).

The search's ``sunk`` is a mean over the source's samples past a margin, in source diagonals: a box 5 mm into a
table top moves it by less than the margin and reads 0. A scene is judged here as a person (and an independent
judge) would measure it, in the scene's units (metres for glTF, by its spec):

- **into another object**: the object's surface samples inside another object, each at its distance to that
  object's surface; and the other way round (a desk leg through a box is the leg's samples inside the box). The
  depth of a pair is the one that ``SHARE`` of a side's samples reach (a spout's tip grazing a wall is not a sunk
  teapot; a box sunk 5 mm into a table has a sixth of its samples 5 mm deep); the object's ``depth`` is its deepest
  pair's. "Inside" is the mesh's own where a piece is closed (its watertight connected pieces: ``contains``); the
  rest of the mesh (open pieces, as real and modelled furniture often has: a slab left open at its back) encloses
  a point where the first surface straight above it and the first straight below it both face away from it
  (``_enclosed``: a sample in that slab sees its top's outside above and its underside's outside below). A lone
  sheet encloses nothing (one of the two rays meets nothing).
- **below the floor**: how far its lowest vertex is under the floor (the base's bottom: the object that stays put).

``SINK`` (5 mm, or ``SINK_SHARE`` of the object's diagonal where that is less) is what counts as sunk: resting
contact leaves a fraction of it. Samples and pieces are kept per mesh (its own file frame) while it lives:
an assembly judges every object many times.
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
import trimesh

from ctp_core.geometry import proximity

__all__ = ["FLOOR", "SHARE", "SINK", "SINK_SHARE", "Sinking", "limit", "sinking"]

SAMPLES = 2000  # surface samples per object
SHARE = 0.01  # the depth a pair is reported at: the one this share of a side's samples reach
SINK = 0.005  # scene units (5 mm in a glTF scene): deeper than this into another object or the floor is sunk
SINK_SHARE = 0.02  # ... or deeper than this share of the object's diagonal, where that is less (a small object)
FLOOR = "the floor"

_PLUMB = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])  # the two rays of ``_enclosed``: straight up, straight down


@dataclass(frozen=True)
class _Solid:
    """What "inside" is measured against for one mesh (its own file frame): its closed pieces and the rest
    (``open``: None where every piece is closed)."""

    closed: list[trimesh.Trimesh]
    open: trimesh.Trimesh | None


_KEPT: dict[int, tuple[np.ndarray, _Solid]] = {}


@dataclass(frozen=True)
class Sinking:
    """The deepest an object is into another (``depth``, scene units; ``into`` names it) and below the floor."""

    depth: float
    into: str | None
    below_floor: float

    def sunk(self, diagonal: float) -> bool:
        """Whether either is past ``limit``."""
        return max(self.depth, self.below_floor) > limit(diagonal)

    def to_dict(self) -> dict:
        """The report's fields, in millimetres (scene units x 1000: glTF's unit is the metre)."""
        depth = round(1000 * self.depth, 1)
        return {"penetration_mm": depth, "into": self.into if depth > 0 else None,
                "below_floor_mm": round(1000 * self.below_floor, 1)}


def limit(diagonal: float) -> float:
    """What counts as sunk for an object of this diagonal (scene units): ``SINK``, or ``SINK_SHARE`` of it."""
    return min(SINK, SINK_SHARE * diagonal)


def sinking(name: str, mesh: trimesh.Trimesh, to_scene: np.ndarray,
            others: Sequence[tuple[str, trimesh.Trimesh, np.ndarray]], floor: float | None,
            skip: Sequence[str] = ()) -> Sinking:
    """How deep ``mesh`` (own file frame, placed by ``to_scene``) is in each of ``others`` ((name, mesh in its own
    file frame, its 4x4 into the scene)) but those named in ``skip`` (a ground the relation goes into), and below
    ``floor`` (scene +Y; None: no floor)."""
    matrix = np.asarray(to_scene, dtype=np.float64)
    points, solid = _kept(mesh)
    placed = trimesh.transform_points(points, matrix)
    deepest, into = 0.0, None
    for other_name, other, other_matrix in others:
        if other_name == name or other_name in skip:
            continue
        other_points, other_solid = _kept(other)
        depth = max(_depth(placed, other_solid, np.asarray(other_matrix, dtype=np.float64)),
                    _depth(trimesh.transform_points(other_points, np.asarray(other_matrix, dtype=np.float64)),
                           solid, matrix))
        if depth > deepest:
            deepest, into = depth, other_name
    below = 0.0
    if floor is not None:
        lowest = float(trimesh.transform_points(np.asarray(mesh.vertices), matrix)[:, 1].min())
        below = max(0.0, floor - lowest)
    return Sinking(deepest, into, below)


def _depth(points: np.ndarray, solid: _Solid, matrix: np.ndarray) -> float:
    """The depth ``SHARE`` of ``points`` (scene frame) reach inside ``solid`` (own frame, placed by ``matrix``),
    scene units; 0 where fewer are inside."""
    if not len(points):
        return 0.0
    scale = float(np.cbrt(abs(np.linalg.det(matrix[:3, :3]))))
    local = trimesh.transform_points(points, np.linalg.inv(matrix))
    depths = np.zeros(len(points))
    for part, inside_of in [*((c, c.contains) for c in solid.closed),
                            *(((solid.open, _enclosed(solid.open)),) if solid.open is not None else ())]:
        low, high = part.bounds
        near = np.flatnonzero(((local >= low) & (local <= high)).all(1))
        if not len(near):
            continue
        inside = near[inside_of(local[near])]
        if len(inside):
            distance = proximity.closest_points(part, local[inside])[1] * scale
            depths[inside] = np.maximum(depths[inside], distance)
    return float(np.quantile(depths, 1.0 - SHARE))


def _enclosed(mesh: trimesh.Trimesh):
    """Whether each point (own frame) is enclosed by ``mesh``'s open pieces: the first faces straight above and
    straight below it both face away from it (the point sees their backs)."""
    def inside(points: np.ndarray) -> np.ndarray:
        out = np.ones(len(points), dtype=bool)
        for ray in _PLUMB:
            first = mesh.ray.intersects_first(points, np.tile(ray, (len(points), 1)))
            hit = first >= 0
            out &= hit
            out[hit] &= mesh.face_normals[first[hit]] @ ray > 0
        return out

    return inside


def _kept(mesh: trimesh.Trimesh) -> tuple[np.ndarray, _Solid]:
    """The mesh's surface samples and what "inside" it is measured against (its own file frame), made once while it
    lives."""
    key = id(mesh)
    kept = _KEPT.get(key)
    if kept is None:
        points = trimesh.sample.sample_surface(mesh, SAMPLES, seed=0)[0]
        plain = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        plain.merge_vertices()
        pieces = [plain] if plain.is_watertight else plain.split(only_watertight=False)
        closed = [p for p in pieces if p.is_watertight]
        rest = [p for p in pieces if not p.is_watertight]
        kept = (np.asarray(points, dtype=np.float64),
                _Solid(closed, cast(trimesh.Trimesh, trimesh.util.concatenate(rest)) if rest else None))
        _KEPT[key] = kept
        weakref.finalize(mesh, _KEPT.pop, key, None)
    return kept
