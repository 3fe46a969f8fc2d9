"""Held-out-like synthetic cases, written to a folder for ``ctp bench``: pairs built the way
``../shared/bench/synthetic`` is (trimesh primitives, metres, +Y up, the source file already at its true pose, so
the reference is the identity), but new objects, sizes and phrasings that no constant was tuned on. They check that
a rule measured on the dev cases (the guide's say, issue 37) holds on cases it never saw; they do not replace the
held-out set acceptance runs on.

    python benchmarks/synthetic_heldout.py /tmp/heldout
    ctp bench /tmp/heldout --with-reference --method geometry --out /tmp/h-geometry --quiet
    ctp bench /tmp/heldout --with-reference --method ctp --guide pixels --out /tmp/h-pixels --quiet

Nothing here is committed data: the folder is made on the run (CC0, generated).
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh
from trimesh.creation import annulus, box, cylinder, icosphere
from trimesh.transformations import rotation_matrix


def _at(mesh: trimesh.Trimesh, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> trimesh.Trimesh:
    mesh.apply_translation((x, y, z))
    return mesh


def _upright(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """A trimesh cylinder or annulus (axis +Z) turned to stand along +Y, its base at y = 0."""
    mesh.apply_transform(rotation_matrix(-math.pi / 2, [1, 0, 0]))
    return _at(mesh, y=-mesh.bounds[0][1])


def _desk() -> trimesh.Trimesh:
    legs = [_at(box((0.05, 0.7, 0.05)), x, 0.35, z) for x in (-0.65, 0.65) for z in (-0.3, 0.3)]
    return trimesh.util.concatenate([_at(box((1.4, 0.05, 0.7)), y=0.725), *legs])


def _shelf() -> trimesh.Trimesh:
    sides = [_at(box((0.03, 1.1, 0.28)), x, 0.55) for x in (-0.42, 0.42)]
    return trimesh.util.concatenate([_at(box((0.81, 0.03, 0.28)), y=0.985), *sides])


def _stool() -> trimesh.Trimesh:
    seat = _at(_upright(cylinder(radius=0.18, height=0.04, sections=40)), y=0.43)
    legs = [_at(_upright(cylinder(radius=0.015, height=0.43, sections=12)), 0.12 * math.cos(a), 0, 0.12 * math.sin(a))
            for a in np.linspace(0, 2 * math.pi, 4, endpoint=False)]
    return trimesh.util.concatenate([seat, *legs])


def _vessel(radius: float, height: float, wall: float) -> trimesh.Trimesh:
    """An open-topped cylinder (a wall ring and a bottom), its base at y = 0."""
    ring = annulus(r_min=radius - wall, r_max=radius, height=height, sections=48)
    ring.apply_translation((0, 0, height / 2))
    bottom = cylinder(radius=radius, height=wall, sections=48)
    bottom.apply_translation((0, 0, wall / 2))
    vessel = trimesh.util.concatenate([ring, bottom])
    vessel.apply_transform(rotation_matrix(-math.pi / 2, [1, 0, 0]))
    return vessel


def _head() -> tuple[trimesh.Trimesh, float]:
    """A sphere head (radius 0.11) on a neck; the height of its centre."""
    centre = 0.3
    neck = _upright(cylinder(radius=0.05, height=0.22, sections=24))
    return trimesh.util.concatenate([neck, _at(icosphere(subdivisions=3, radius=0.11), y=centre)]), centre


def _cap_on(head_centre: float, radius: float = 0.11) -> trimesh.Trimesh:
    """An upside-down cup worn on the head: its inner rim (radius a) rests where the sphere is that wide."""
    outer, wall, depth = 0.095, 0.006, 0.06
    cap = _vessel(outer, depth, wall)
    cap.apply_transform(rotation_matrix(math.pi, [1, 0, 0]))  # the opening down, its rim at y = 0
    a = outer - wall  # the opening, now at y = -depth, goes to the height where the sphere is a wide
    return _at(cap, y=head_centre + math.sqrt(radius * radius - a * a) + depth)


def _board_leaning(wall_face: float, tilt_deg: float) -> trimesh.Trimesh:
    """A 0.6 x 1.0 x 0.03 board standing on the floor, its top tilted toward -Z onto a wall face at z = wall_face."""
    board = box((0.6, 1.0, 0.03))
    board.apply_transform(rotation_matrix(-math.radians(tilt_deg), [1, 0, 0]))
    lo = board.bounds[0]
    return _at(board, y=-lo[1], z=wall_face - lo[2])


def cases() -> dict[str, tuple[str, str, str, str, Callable[[], tuple[trimesh.Trimesh, trimesh.Trimesh]]]]:
    """id -> (prompt, target name, source name, coarse relation, build)."""
    def crate_under_desk():
        return _desk(), _at(box((0.32, 0.26, 0.3)), y=0.13)

    def ball_beside_cabinet():
        ball = icosphere(subdivisions=3, radius=0.12)
        return _at(box((0.6, 1.0, 0.4)), y=0.5), _at(ball, x=0.3 + 0.12 + 0.02, y=0.12)

    def egg_in_bowl():
        egg = icosphere(subdivisions=3, radius=1.0)
        egg.apply_scale((0.025, 0.034, 0.025))
        return _vessel(0.09, 0.06, 0.005), _at(egg, y=0.005 + 0.034)

    def cap_on_head():
        head, centre = _head()
        return head, _cap_on(centre)

    def vase_on_shelf():
        return _shelf(), _at(_upright(cylinder(radius=0.05, height=0.22, sections=32)), y=1.0)

    def box_below_shelf():
        return _shelf(), _at(box((0.3, 0.3, 0.2)), y=0.15)

    def board_against_wall():
        return _at(box((2.0, 1.5, 0.1)), y=0.75), _board_leaning(0.05, 15.0)

    def mug_on_stool():
        return _stool(), _at(_vessel(0.045, 0.1, 0.004), y=0.47)

    return {
        "hs-01": ("a crate under the desk", "desk", "crate", "under", crate_under_desk),
        "hs-02": ("a ball beside the cabinet", "cabinet", "ball", "beside", ball_beside_cabinet),
        "hs-03": ("an egg in the bowl", "bowl", "egg", "inside", egg_in_bowl),
        "hs-04": ("a man's head wearing a cap", "head", "cap", "on_head", cap_on_head),
        "hs-05": ("a vase on the shelf", "shelf", "vase", "on_top", vase_on_shelf),
        "hs-06": ("a box below the shelf", "shelf", "box", "under", box_below_shelf),
        "hs-07": ("a board leaning against the wall", "wall", "board", "leaning_against", board_against_wall),
        "hs-08": ("a mug on the stool", "stool", "mug", "on_top", mug_on_stool),
    }


def write(folder: Path) -> list[Path]:
    """Each case as ``folder/<id>/{target.glb, source.glb, case.json}``; the written folders."""
    written = []
    for case_id, (prompt, target_name, source_name, relation, build) in cases().items():
        target, source = build()
        where = folder / case_id
        where.mkdir(parents=True, exist_ok=True)
        target.export(where / "target.glb")
        source.export(where / "source.glb")
        case = {"id": case_id, "prompt": prompt, "origin": "synthetic",
                "target": {"file": "target.glb", "name": target_name},
                "source": {"file": "source.glb", "name": source_name},
                "reference": {"source_to_target": np.eye(4).tolist(), "scale": 1.0}, "relation": relation,
                "penetration_expected": False, "license": {"target": "CC0 (generated)", "source": "CC0 (generated)"}}
        (where / "case.json").write_text(json.dumps(case, indent=1))
        written.append(where)
    return written


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python benchmarks/synthetic_heldout.py FOLDER")
    for path in write(Path(sys.argv[1])):
        print(path)
