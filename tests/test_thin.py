"""Thin parts of the ground (``relations.thin``): bars, openings and their rims, found on generated grounds whose
parts are known by construction, named in the parts' report, and preferred by ``hang`` and ``in``.

Meshes are built in their file frame, +Y up, the glTF front (+Z); pairs are prepared as ``test_directions`` does.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import trimesh
from test_directions import gltf, prepared
from test_parts import _run, bookcase, crate, cushion, desk, dining_chair, pen_holder, prefer_and_score, towel_rail
from test_predicates import box, pose

from ctp_core import export
from ctp_core.relations import parts, thin


def _numbers(line: str, after: str) -> float:
    return float(re.search(re.escape(after) + r" ([0-9.e+-]+)", line).group(1))


def bucket(handle: bool = True) -> trimesh.Trimesh:
    """An open box 0.3 x 0.3, 0.25 tall (walls and floor 0.01 thick), with a handle 0.02 thick arching over its
    middle along x, its top 0.4 above the floor."""
    pieces = [box([0.3, 0.01, 0.3], [0, 0.005, 0])]
    pieces += [box([0.01, 0.25, 0.3], [x, 0.125, 0]) for x in (-0.145, 0.145)]
    pieces += [box([0.28, 0.25, 0.01], [0, 0.125, z]) for z in (-0.145, 0.145)]
    if handle:
        pieces += [box([0.3, 0.02, 0.02], [0, 0.39, 0])]
        pieces += [box([0.02, 0.15, 0.02], [x, 0.315, 0]) for x in (-0.14, 0.14)]
    return gltf(trimesh.util.concatenate(pieces))


def tray() -> trimesh.Trimesh:
    """A tray 0.5 x 0.35 with a rim 0.02 high: a shallow dish, no opening."""
    pieces = [box([0.5, 0.01, 0.35], [0, 0.005, 0])]
    pieces += [box([0.01, 0.03, 0.35], [x, 0.015, 0]) for x in (-0.245, 0.245)]
    pieces += [box([0.48, 0.03, 0.01], [0, 0.015, z]) for z in (-0.17, 0.17)]
    return gltf(trimesh.util.concatenate(pieces))


def frame() -> trimesh.Trimesh:
    """Four beams 0.05 thick round an empty square 0.4 wide, lying on the floor: holds no water."""
    pieces = [box([0.5, 0.2, 0.05], [0, 0.1, z]) for z in (-0.225, 0.225)]
    pieces += [box([0.05, 0.2, 0.4], [x, 0.1, 0]) for x in (-0.225, 0.225)]
    return gltf(trimesh.util.concatenate(pieces))


def test_water_stands_inside_a_rim_drawn_corner_to_corner_and_drains_outside():
    height = np.zeros((7, 7))
    ring = [(1, 3), (2, 2), (3, 1), (4, 2), (5, 3), (4, 4), (3, 5), (2, 4)]  # a diamond, its cells touching at corners
    for i, j in ring:
        height[i, j] = 2.0
    level = thin.water_level(height)
    assert level[3, 3] == 2.0  # held: water flows to the four neighbours only
    assert level[0, 0] == 0.0 and level[6, 6] == 0.0
    height[1, 3] = 1.0  # a notch in the rim: the water spills there
    assert thin.water_level(height)[3, 3] == 1.0


def test_a_towel_rail_s_longest_bar_is_its_rail_and_its_wall_plate_is_none():
    found = parts.thin_parts(prepared(towel_rail(), cushion()))
    assert found.bars and not found.openings, found.describe()
    # the rail (and the posts that hold it, rods too), at y 1.0; the plate's top edge (y 1.1) is thicker than wide
    assert all(abs((b.middle[1] - found.floor) * found.unit - 0.1) < 0.02 for b in found.bars), found.describe()
    line = found.bars[0].describe(found.unit, found.floor)
    assert 0.7 <= _numbers(line, "a bar:") <= 0.85, line  # 0.8 long (its posts and the plate's top are not it)
    assert 0.015 <= _numbers(line, "long,") <= 0.03, line  # 0.02 thick
    assert line in found.describe() and line in parts.describe(prepared(towel_rail(), cushion()))


def test_a_pen_holder_has_an_opening_with_its_rim_at_its_top():
    found = parts.thin_parts(prepared(pen_holder(), cushion()))
    assert len(found.openings) == 1, found.describe()
    opening, rim = found.openings[0].describe(found.unit, found.floor)
    assert 0.06 <= _numbers(opening, "an opening:") <= 0.08, opening  # 0.072 inside
    assert 0.085 <= _numbers(opening, "across,") <= 0.1, opening  # 0.095 deep
    assert rim.startswith("a rim:") and abs(_numbers(rim, "across,") - 0.1) < 0.005, rim
    assert opening in found.describe() and rim in found.describe()


def test_a_bucket_has_one_opening_under_its_handle_and_the_handle_is_a_bar():
    found = parts.thin_parts(prepared(bucket(), cushion()))
    assert len(found.openings) == 1, found.describe()  # one opening: the handle over it does not split it
    assert abs(found.openings[0].depth * found.unit - 0.24) < 0.02, found.describe()
    assert abs(found.openings[0].rim - found.floor - 0.25 / found.unit) < 0.02 / found.unit
    bars = [b for b in found.bars if abs((b.middle[1] - found.floor) * found.unit - 0.4) < 0.02]
    assert len(bars) == 1 and abs(bars[0].axis[0]) > 0.95, found.describe()  # the handle, along x


def test_furniture_boards_trays_and_frames_are_neither_bars_nor_openings():
    for ground in (desk(), bookcase(), dining_chair(), tray(), frame()):
        found = parts.thin_parts(prepared(ground, cushion()))
        assert not found.openings, found.describe()
    for ground in (desk(), bookcase(), tray()):
        assert not parts.thin_parts(prepared(ground, cushion())).bars, ground


def test_hang_prefers_the_bar_to_the_top_edge_of_the_wall_plate_behind_it():
    ring = gltf(trimesh.creation.annulus(r_min=0.03, r_max=0.04, height=0.01))
    ring.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))  # the ring's plane x-y
    # hung at the middle, the top of its loop's inside on the bar's top (y 1.01) or over the plate's top edge (y 1.1,
    # z -0.005; the ring turned to cross it)
    across = trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0])[:3, :3]
    on_bar, on_plate = pose([0, 1.01 - 0.03, 0.1]), pose([0, 1.1 - 0.03, -0.005], across)
    prefer, score = prefer_and_score(towel_rail(), ring, [on_bar, on_plate], "hang")
    assert prefer[0] < prefer[1], (prefer, score)


def test_in_prefers_standing_in_through_the_opening_to_lying_through_its_wall():
    pencil = trimesh.creation.cylinder(radius=0.004, height=0.12, sections=12)
    pencil.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))  # along +Y
    standing = pose([0.0, 0.066, 0.0])
    lying = np.eye(4)
    lying[:3, :3] = trimesh.transformations.rotation_matrix(math.pi / 2, [0, 0, 1])[:3, :3]
    lying[:3, 3] = [0.0, 0.03, 0.0]
    prefer, _ = prefer_and_score(pen_holder(), gltf(pencil), [standing, lying], "in")
    assert prefer[0] < prefer[1], prefer


def test_a_crate_in_front_reports_no_thin_parts_of_its_own():
    """A closed box has neither: its top is a board, its inside closed."""
    found = parts.thin_parts(prepared(crate(0.3), cushion()))
    assert not found.bars and not found.openings, found.describe()


def test_a_run_hanging_a_ring_on_a_towel_rail_names_the_bar_in_its_report_and_hangs_on_it():
    ring = gltf(trimesh.creation.annulus(r_min=0.03, r_max=0.04, height=0.01))
    ring.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))
    result, centre = _run(towel_rail(), ring, "a ring hanging on the towel rail", "towel rail", "ring")
    named = export.report(result)["extra"]["parts"]
    assert any(line.startswith("a bar:") and 0.7 <= _numbers(line, "a bar:") <= 0.85 for line in named), named
    assert result.relation["holds"] and "bar" in result.relation["usual"], result.relation
    assert abs(centre[0]) < 0.2 and centre[2] > 0.05, centre  # on the rail (z 0.1), toward its middle


def test_specks_scattered_over_a_wide_box_keep_the_grids_small():
    """Samples far apart for the box they span (a few tiny triangles over a metre): the height map and a crest's
    disc stay within ``GRID`` cells a side instead of one cell per spacing (billions of them)."""
    rng = np.random.default_rng(0)
    points = rng.random((20000, 3))
    widest = float(np.ptp(points[:, [0, 2]], axis=0).max())
    height, _, cell = thin.height_map(points, 1e-6)
    assert max(height.shape) <= thin.GRID + 1 and cell == pytest.approx(widest / thin.GRID)
    assert thin.inscribed(points[:, [0, 2]], 1e-6) >= widest / thin.GRID
    normals = np.tile([0.0, 1.0, 0.0], (len(points), 1))
    assert thin.find_openings(points, 1e-6) == [] and thin.find_bars(points, normals, 1e-6) == []


def test_column_neighbours_are_every_pair_within_the_radius_across():
    """Against all pairs measured directly: the height is ignored, a pair at exactly the radius counts, and a sample
    straight above another (no horizontal distance) is its neighbour."""
    rng = np.random.default_rng(3)
    tops, points = rng.uniform(0, 1, (40, 3)), rng.uniform(0, 1, (300, 3))
    points[0] = tops[0] + [0.0, 0.5, 0.0]  # straight above
    points[1] = tops[1] + [0.1, -0.3, 0.0]  # exactly the radius across
    row, other = thin.column_neighbours(tops, points, 0.1)
    across = np.linalg.norm(tops[:, None, [0, 2]] - points[None, :, [0, 2]], axis=-1)
    expected = {(i, j) for i, j in zip(*np.nonzero(across <= 0.1), strict=True)}
    assert set(zip(row.tolist(), other.tolist(), strict=True)) == expected and len(row) == len(expected)
    assert (0, 0) in expected and (1, 1) in expected
