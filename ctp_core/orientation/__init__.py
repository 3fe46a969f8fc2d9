"""Which way is up and which way is front for one object, and why: the file's own convention first.

A guess from geometry can be wrong in ways a placement cannot survive (a table turned onto its top puts "a cup on
the table" at the foot of a leg, and the relation then holds on the flipped table), while a file that states its
axes is right by construction. So, per object (``Axes``, the options ``up`` and ``front``):

- ``file`` (the default): the file's convention.
  - glTF / GLB: the spec (glTF 2.0, section 3.4) says +Y is up and an asset's front faces +Z: both kept, the front
    trusted (unless the object is rotationally symmetric about its up: then no side is its front).
  - OBJ, STL, PLY and meshes made in code: no convention. The rule: Y-up, unless the object stands on legs
    (``canonical.resting_poses``' feet) with the file's +Z up and not with its +Y up: a Z-up export (CAD, 3D
    printing, Blender's own axes). Legs only: by flat bases a wall with a peg (a hull that topples forward off its
    edge) would be laid on its back. The front is +Z (Y-up) or -Y (Z-up, Blender's front view), not trusted.
    Only +Y or +Z can come out, so this rule never turns an object upside down.
- a signed axis (``+x``, ``-y``, ...): that axis of the file, trusted.
- ``auto``: the geometric guess: ``canonical.upright_rotation`` for up (its resting-pose, legs and symmetry cues,
  or the judge), ``guessed_front`` for front; neither trusted as a convention is.

The result is a ``canonical.Upright``: the rotation file -> upright frame (+Y up), the front in the file frame,
and the reasons the report gives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import get_args

import numpy as np
import trimesh

from ctp_core.config import AlignConfig, Direction, crossing
from ctp_core.errors import ConfigError
from ctp_core.geometry import sampling
from ctp_core.orientation import canonical

DIRECTIONS: tuple[str, ...] = get_args(Direction)
CONVENTIONS = {"glb": "glTF", "gltf": "glTF"}  # file formats whose spec fixes up (+Y) and front (+Z)
_AXES = {"x": 0, "y": 1, "z": 2}
_Y, _Z = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
_Z_UP_COS = np.cos(np.radians(10.0))  # a resting pose this close to an axis stands with that axis up
_FRONT_OFFSET = 0.05  # share of the longest side the surface must gather off centre for a front to be guessed
_FRONT_SAMPLES = 4000


@dataclass(frozen=True)
class Axes:
    """The options of one object: where its up and its front come from (``DIRECTIONS``)."""

    up: Direction = "file"
    front: Direction = "file"

    def __post_init__(self) -> None:
        for name in ("up", "front"):
            if getattr(self, name) not in DIRECTIONS:
                raise ConfigError(f"{name} must be one of {', '.join(DIRECTIONS)}, not {getattr(self, name)!r}",
                                  field=name)
        if crossing(self.up, self.front):
            raise ConfigError(f"front {self.front} is not at right angles to up {self.up}", field="front")


FROM_FILE = Axes()  # the default: up and front from the file


def configured(config: AlignConfig) -> dict[str, Axes]:
    """``pairs.prepare_pair``'s ``target_axes`` and ``source_axes`` from a configuration; ``upright_judge`` lets the
    guidance model choose among the target's candidate ups as ``auto`` does (unless an axis is given)."""
    judged = config.upright_judge and config.target_up in ("file", "auto")
    return {"target_axes": Axes("auto" if judged else config.target_up, config.target_front),
            "source_axes": Axes(config.source_up, config.source_front)}


def axis(name: str) -> np.ndarray:
    """``+x`` .. ``-z`` as a unit vector of the file frame."""
    vector = np.zeros(3)
    vector[_AXES[name[1]]] = 1.0 if name[0] == "+" else -1.0
    return vector


def file_format(mesh: trimesh.Trimesh) -> str | None:
    """The format the mesh was read from (``io`` records it), None for a mesh made in code."""
    return mesh.metadata.get("file_format")


def orient(mesh: trimesh.Trimesh, axes: Axes = FROM_FILE, *, seed: int = 0, judge: canonical.Judge | None = None,
           role: str = "target") -> canonical.Upright:
    """Up (as the rotation file -> upright frame) and front (file frame) of ``mesh`` by ``axes``, with reasons.

    ``judge``: lets a guidance model choose among candidate ups where ``up`` is ``auto``; ``role`` names the
    option a refused front is reported on (``<role>_front``).
    """
    fmt = file_format(mesh)
    convention = CONVENTIONS.get(fmt or "")
    if axes.up == "auto":
        guess = canonical.upright_rotation(mesh, seed=seed, judge=judge)
        how = "the guidance model's judgement" if judge is not None else "geometric guess"
        upright = canonical.Upright(guess.rotation, guess.changed, f"up: auto ({how}): {guess.reason}", guess.axes,
                                    guess.candidates)
    elif axes.up != "file":
        up = axis(axes.up)
        upright = _standing(up, f"up: {axes.up} as given")
    elif convention:
        upright = canonical.identity(f"up: +Y, as every {convention} file has it")
    else:
        upright = _unstated(mesh, fmt)
    up = upright.up
    upright.symmetric = _symmetric_about(mesh, up, seed)
    convention_up = _Y if convention or np.allclose(up, _Y) or up @ _Z < _Z_UP_COS else _Z
    convention_front = _Z if convention_up is _Y else -_Y
    if axes.front == "auto":
        front, trusted, why = guessed_front(mesh, up, seed)
    elif axes.front != "file":
        front, trusted, why = axis(axes.front), True, f"front: {axes.front} as given"
        if abs(front @ up) > 0.5:
            raise ConfigError(f"front {axes.front} is not at right angles to the up "
                              f"{np.round(up, 3).tolist()}", field=f"{role}_front")
    else:
        # the convention's front, turned as the up was turned away from the convention's up (if it was); a glTF's
        # nodes that turn the object about its up carry its front (``io.node_front``)
        node = mesh.metadata.get("front") if convention else None
        if node is not None:
            convention_front = np.asarray(node, dtype=np.float64)
        front = canonical.turn_onto(convention_up, up) @ convention_front
        trusted = bool(convention) and axes.up in ("file", "+y")
        why = (f"front: {_named(front)}, every {convention} file's +Z, turned by the file's node" if node is not None
               else f"front: {_named(front)}, as every {convention} file has it" if convention
               else f"front: {_named(front)}, the usual front of a {'Y' if convention_up is _Y else 'Z'}-up export "
                    f"({fmt or 'a mesh made in code'} states none): not trusted")
        if trusted and upright.symmetric:
            trusted, why = False, f"{why}; the object is symmetric about its up, so no side is its front"
    front = front - (front @ up) * up
    front /= np.linalg.norm(front)
    upright.front, upright.front_trusted, upright.front_reason = front, trusted, why
    return upright


def _unstated(mesh: trimesh.Trimesh, fmt: str | None) -> canonical.Upright:
    """The stated rule for a file without an up convention: Y-up, unless the object stands on legs with the
    file's +Z up and not with its +Y up."""
    what = f"{fmt.upper()} states no up" if fmt else "a mesh made in code states no up"
    poses = canonical.unit_resting_poses(mesh)
    y, z = _pose(poses, _Y), _pose(poses, _Z)
    if z is not None and z["feet"] >= canonical.LEGS and (y is None or y["feet"] < canonical.LEGS):
        return _standing(_Z, f"up: +Z ({what}; it stands on legs with the file's +Z up, not its +Y: a Z-up export)")
    return canonical.identity(f"up: +Y ({what}; Y-up unless it stands on legs with the file's +Z up only)")


def _pose(poses: list[dict], up: np.ndarray) -> dict | None:
    """The best resting pose with ``up`` (file frame), or None."""
    return next((p for p in poses if np.dot(p["up"], up) > _Z_UP_COS), None)


def _standing(up: np.ndarray, reason: str) -> canonical.Upright:
    """The upright of an up given exactly: the smallest turn of ``up`` onto +Y."""
    rotation = canonical.turn_onto(up, _Y)
    return canonical.Upright(rotation, not np.allclose(rotation, np.eye(3)), reason)


def guessed_front(mesh: trimesh.Trimesh, up: np.ndarray, seed: int = 0) -> tuple[np.ndarray, bool, str]:
    """The front from geometry: away from the side the surface gathers at (a backrest, a screen's stand, a
    headboard), snapped to the nearest horizontal dominant axis; (front, trusted, reason) in the file frame.

    Not trusted either way (a guess); where the surface gathers at no side, the file's +Z (made horizontal)."""
    points, _ = sampling.surface_samples(mesh, _FRONT_SAMPLES, seed)
    offset = points.mean(0) - mesh.bounds.mean(0)
    offset -= (offset @ up) * up
    if np.linalg.norm(offset) < _FRONT_OFFSET * float(mesh.extents.max()):
        fallback = _Z if abs(_Z @ up) < 0.9 else -_Y
        return fallback, False, f"front: auto found no side the surface gathers at; {_named(fallback)}, not trusted"
    axes = canonical.dominant_axes(canonical.unit_size(mesh), seed)
    horizontal = [a for a in axes if abs(a @ up) < np.sin(np.radians(10.0))]
    front = -offset / np.linalg.norm(offset)
    if horizontal:
        nearest = max(horizontal, key=lambda a: abs(a @ front))
        front = nearest * np.sign(nearest @ front)
    return front, False, f"front: auto (geometric guess): {_named(front)}, away from where the surface gathers"


def _symmetric_about(mesh: trimesh.Trimesh, up: np.ndarray, seed: int) -> bool:
    symmetry = canonical.symmetry_axis(canonical.unit_size(mesh), seed)
    return symmetry is not None and abs(symmetry @ up) > np.cos(np.radians(10.0))


def _named(vector: np.ndarray) -> str:
    """``+z`` for a vector along an axis, else its rounded components."""
    k = int(np.argmax(np.abs(vector)))
    if abs(vector[k]) > 0.999:
        return ("+" if vector[k] > 0 else "-") + "xyz"[k]
    return str(np.round(vector, 3).tolist())


def to_dict(upright: canonical.Upright) -> dict:
    """The report's fields of one object's frame: up and front (file frame), whether the front is trusted, why."""
    return {"up": _rounded(upright.up), "front": _rounded(upright.front), "front_trusted": upright.front_trusted,
            "reason": upright.reason, "front_reason": upright.front_reason}


def _rounded(vector: np.ndarray) -> list[float]:
    return [round(float(v), 6) + 0.0 for v in vector]
