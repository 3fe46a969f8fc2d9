"""The ground's parts (``relations.parts``) and each relation's usual place on generated furniture whose parts are
known by construction: a dining chair, a bookcase, a desk, a cabinet, a towel rail.

Meshes are built in their file frame, +Y up, the glTF front (+Z); pairs are prepared as ``test_directions`` does.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from test_directions import gltf, prepared
from test_predicates import box, pose, poses

from ctp_core import export
from ctp_core.align import align
from ctp_core.config import AlignConfig
from ctp_core.reading import places
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import parts, predicates


def dining_chair() -> trimesh.Trimesh:
    """A seat 0.45 x 0.45 (its top at 0.47) on four legs, a back 0.45 wide rising behind it (along -Z) to 1.0."""
    pieces = [box([0.45, 0.04, 0.45], [0, 0.45, 0]), box([0.45, 0.55, 0.04], [0, 0.745, -0.205])]
    pieces += [box([0.04, 0.43, 0.04], [x, 0.215, z]) for x in (-0.2, 0.2) for z in (-0.2, 0.2)]
    return gltf(trimesh.util.concatenate(pieces))


def bookcase() -> trimesh.Trimesh:
    """Boards at 0.02, 0.32, 0.62 and a top at 0.92 (0.9 wide, 0.3 deep), two sides and a back."""
    pieces = [box([0.9, 0.04, 0.3], [0, y, 0]) for y in (0.02, 0.32, 0.62, 0.92)]
    pieces += [box([0.04, 0.94, 0.3], [x, 0.47, 0]) for x in (-0.47, 0.47)]
    pieces += [box([0.98, 0.94, 0.02], [0, 0.47, -0.16])]
    return gltf(trimesh.util.concatenate(pieces))


def cabinet() -> trimesh.Trimesh:
    """A tall cabinet 0.5 wide, 0.4 deep, 1.5 high, facing +Z."""
    return gltf(box([0.5, 1.5, 0.4], [0, 0.75, 0]))


def desk() -> trimesh.Trimesh:
    """A top 1.2 x 0.6 (its upper face at 0.75) on four legs."""
    pieces = [box([1.2, 0.04, 0.6], [0, 0.73, 0])]
    pieces += [box([0.04, 0.71, 0.04], [x, 0.355, z]) for x in (-0.57, 0.57) for z in (-0.27, 0.27)]
    return gltf(trimesh.util.concatenate(pieces))


def towel_rail() -> trimesh.Trimesh:
    """A bar 0.8 long (x), 0.02 thick, at y = 1.0, held by two posts from a wall plate behind it."""
    pieces = [box([0.8, 0.02, 0.02], [0, 1.0, 0.1]), box([0.9, 0.2, 0.01], [0, 1.0, -0.005])]
    pieces += [box([0.02, 0.02, 0.1], [x, 1.0, 0.05]) for x in (-0.39, 0.39)]
    return gltf(trimesh.util.concatenate(pieces))


def cushion() -> trimesh.Trimesh:
    return gltf(box([0.36, 0.08, 0.36], [0, 0, 0]))


def crate(side: float = 0.3) -> trimesh.Trimesh:
    return gltf(box([side, side, side], [0, 0, 0]))


def prefer_and_score(target, source, matrices, relation, place=None):
    pair = prepared(target, source)
    reading = RelationReading.parse(relation, place=place)
    p = poses(pair, matrices)
    return predicates.preference(pair, p, reading), predicates.relation_score(pair, p, reading)


# --- the parts ---------------------------------------------------------------------------------------------------

def test_a_chair_has_a_seat_with_a_back_and_its_backrest_top_is_the_top():
    found = parts.find_parts(prepared(dining_chair(), cushion()))
    names = [s.name for s in found.surfaces]
    assert names[0] == "top" and "seat" in names, names
    seat = found.surfaces[names.index("seat")]
    assert "a back rising behind it" in seat.reason, seat.reason
    assert seat.height < found.surfaces[0].height


def test_a_bookcase_has_its_top_and_three_shelves_in_order():
    found = parts.find_parts(prepared(bookcase(), crate(0.15)))
    names = [s.name for s in found.surfaces]
    assert names == ["top", "shelf", "shelf", "shelf"], [(s.name, s.reason) for s in found.surfaces]


def test_the_back_of_a_ground_with_a_front_is_against_the_wall_and_the_others_are_reached():
    pair = prepared(cabinet(), crate())
    sides = parts.find_parts(pair).sides
    assert [name for name, s in sides.items() if not s.accessible] == ["behind"]
    pair.front_trusted = False
    # the cache keeps the first: build afresh with no front
    assert all(s.accessible for s in parts.find_parts.__wrapped__(pair).sides.values())


@pytest.mark.parametrize(("place", "board"), [(None, 0.94), ("top", 0.94), ("middle shelf", 0.34),
                                              ("lower shelf", 0.04), ("upper shelf", 0.64)])
def test_the_usual_surface_is_the_highest_that_fits_or_the_one_the_prompt_names(place, board):
    pair = prepared(bookcase(), crate(0.15))
    surface = parts.usual_spot(pair, pair.source_diagonal, place).surface
    height_in_file = (surface.height - pair.floor) / pair.target_to_normalised.scale
    assert height_in_file == pytest.approx(board, abs=0.02), (place, surface.reason)


def test_the_seat_is_the_usual_surface_of_a_chair_for_a_cushion_not_the_backrest_top():
    pair = prepared(dining_chair(), cushion())
    assert parts.usual_spot(pair, pair.source_diagonal, None).surface.name == "seat"


# --- the usual place of each relation ----------------------------------------------------------------------------

def test_on_a_chair_prefers_the_middle_of_the_seat_to_its_edge_and_to_the_backrest_top():
    middle, edge = pose([0, 0.51, 0.02]), pose([0.12, 0.51, 0.1])
    on_back = pose([0, 1.06, -0.205], np.diag([1.0, 1.0, 1.0]))
    prefer, score = prefer_and_score(dining_chair(), cushion(), [middle, edge, on_back], "on")
    assert predicates.holds(score[:2]).tolist() == [True, True], score
    assert prefer[0] < prefer[1] < prefer[2], prefer


def test_on_the_middle_shelf_holds_there_and_is_preferred_to_the_top():
    on_middle, on_top = pose([0, 0.415, 0]), pose([0, 1.015, 0])
    prefer, score = prefer_and_score(bookcase(), crate(0.15), [on_middle, on_top], "on", "middle shelf")
    assert predicates.holds(score).tolist() == [True, True], score
    assert prefer[0] < prefer[1] - 0.5, prefer
    plain, plain_score = prefer_and_score(bookcase(), crate(0.15), [on_middle, on_top], "on")
    assert predicates.holds(plain_score).tolist() == [False, True]  # unnamed, a shelf under a board is not "on"
    assert plain[1] < plain[0]


def test_at_the_edge_of_prefers_the_edge_to_the_middle():
    middle, edge = pose([0, 0.9, 0]), pose([0.5, 0.9, 0.2])
    prefer, score = prefer_and_score(desk(), crate(0.3), [middle, edge], "on", "edge")
    assert predicates.holds(score).tolist() == [True, True], score
    assert prefer[1] < prefer[0], prefer


@pytest.mark.parametrize("side", ["left", "right", "front"])
def test_a_side_prefers_its_middle_a_hands_width_out_to_its_corner_and_far_out(side):
    way = {"left": np.array([1.0, 0, 0]), "right": np.array([-1.0, 0, 0]), "front": np.array([0, 0, 1.0])}[side]
    across = np.array([way[2], 0, -way[0]])
    reach = 0.6 if side != "front" else 0.3
    centred = way * (reach + 0.2) + [0, 0.15, 0]
    corner = way * (reach + 0.2) + across * (0.28 if side == "front" else 0.25) + [0, 0.15, 0]
    far = way * (reach + 0.4) + [0, 0.15, 0]
    prefer, score = prefer_and_score(desk(), crate(), [pose(centred), pose(corner), pose(far)], side)
    assert predicates.holds(score).tolist() == [True, True, True], score
    assert prefer[0] < prefer[1] and prefer[0] < prefer[2], prefer


def test_beside_prefers_a_lateral_side_to_the_front():
    lateral, front = pose([0.8, 0.15, 0]), pose([0, 0.15, 0.5])
    prefer, score = prefer_and_score(desk(), crate(), [lateral, front], "beside")
    assert predicates.holds(score).tolist() == [True, True], score
    assert prefer[0] < prefer[1], prefer


def _leaning_board(position, facing):
    """A board 1.0 tall leaning 15 degrees toward the ground at ``position`` (its centre), ``facing`` out."""
    board = gltf(box([0.3, 1.0, 0.04], [0, 0, 0]))
    tilts = {"+z": ([1, 0, 0], -15), "-z": ([1, 0, 0], 15), "+x": ([0, 0, 1], 15), "-x": ([0, 0, 1], -15)}
    axis, degrees = tilts[facing]
    return board, pose(position, trimesh.transformations.rotation_matrix(math.radians(degrees), axis)[:3, :3])


def test_lean_prefers_a_side_of_a_cabinet_to_its_back():
    board, on_side = _leaning_board([0.25 + 0.15, 0.483, 0], "+x")
    _, on_back = _leaning_board([0, 0.483, -0.2 - 0.15], "-z")
    prefer, score = prefer_and_score(cabinet(), board, [on_side, on_back], "lean")
    assert predicates.holds(score).tolist() == [True, True], score
    assert prefer[0] < prefer[1], prefer


def test_hang_prefers_the_middle_of_the_rail_to_its_end():
    hook = gltf(trimesh.creation.annulus(r_min=0.03, r_max=0.04, height=0.01))
    hook.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))  # the ring's plane x-y
    middle, end = pose([0, 1.0 - 0.03 + 0.01 - 0.0, 0.1]), pose([0.3, 1.0 - 0.02, 0.1])
    prefer, _ = prefer_and_score(towel_rail(), hook, [middle, end], "hang")
    assert prefer[0] < prefer[1], prefer


# --- the prompt's place ------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("prompt", "place"), [
    ("a trophy on the middle shelf of the bookcase", "middle shelf"),
    ("a book on the bottom shelf", "lower shelf"),
    ("a vase on the top shelf", "top shelf"),
    ("a cup at the edge of the table", "edge"),
    ("a plant in the corner of the desk", "corner"),
    ("a lamp at the left end of the sideboard", "left end"),
    ("a cross on top of the church", "top"),
    ("a pillow at the head of the bed", "head"),
    ("a cup on the table", None),
    ("a cushion on the dining chair", None),
])
def test_the_prompt_names_a_place(prompt, place):
    assert places.read_place(prompt) == place


def test_the_priors_carry_the_place_to_the_reading():
    from ctp_core import priors

    prior = priors.resolve_priors(priors.get_provider("rules"), "bookcase", "trophy",
                                  "a trophy on the middle shelf of the bookcase")
    assert prior.reading.place == "middle shelf" and prior.reading.name == "on"


# --- whole runs (geometry only, the ``default`` preset: the ``test`` preset's dozen candidates are too few to judge
# where the search puts the usual place) ------------------------------------------------------------------------

def _run(target, source, prompt, target_name, source_name):
    config = AlignConfig.from_preset("default").merged({"loss": {"lambda_clip": 0.0}, "threads": 1})
    source = source.copy()
    source.apply_translation([3.0, 0.5, 2.0])
    result = align(target, source, prompt, config, target_name=target_name, source_name=source_name)
    placed = source.copy()
    placed.apply_transform(result.source_to_target)
    return result, placed.bounds.mean(axis=0)


def test_a_cushion_on_a_dining_chair_ends_on_the_seat_and_the_report_names_it():
    result, centre = _run(dining_chair(), cushion(), "a cushion on the dining chair", "dining chair", "cushion")
    assert result.relation["holds"], result.relation
    assert centre[1] < 0.6 and abs(centre[0]) < 0.1, centre  # on the seat (its top at 0.47), not the back (1.0)
    assert result.relation["usual"].startswith("the seat"), result.relation["usual"]
    assert result.relation["pose"].startswith("standing as it is set down"), result.relation["pose"]
    written = export.report(result)  # the report names every part with why
    assert written["extra"]["parts"] == result.ground_parts and any(
        line.startswith("the seat") for line in written["extra"]["parts"]), written["extra"]["parts"]


def test_a_crate_left_of_a_desk_ends_centred_on_its_left_side():
    result, centre = _run(desk(), crate(), "a crate to the left of the desk", "desk", "crate")
    assert result.relation["holds"], result.relation
    assert centre[0] > 0.6 and abs(centre[2]) < 0.15, centre  # the desk's own left is +X; centred along z


def test_the_parts_registry_is_consistent_and_its_check_sees_a_broken_one():
    assert parts.check(parts.PARTS) == []
    assert [p.name for p in parts.PARTS.values() if p.detect is not None][-1] == "surface"  # it takes every surface
    no_shelf = {name: part for name, part in parts.PARTS.items() if name != "shelf"}
    problems = parts.check(no_shelf)
    assert "shelf: a part name without a part" in problems
    assert any(p.startswith("lower shelf: selects 0 parts") for p in problems), problems
    twice = {**parts.PARTS, "top": replace(parts.PARTS["top"], places=frozenset({places.Place.TOP, places.Place.EDGE}))}
    assert any(p.startswith("edge: selects 2 parts") for p in parts.check(twice))


def stepped_block() -> trimesh.Trimesh:
    """A block 0.6 wide with a step: its top at 0.5 over x < 0, a lower step at 0.25 over x > 0."""
    pieces = [box([0.3, 0.5, 0.4], [-0.15, 0.25, 0]), box([0.3, 0.25, 0.4], [0.15, 0.125, 0])]
    return gltf(trimesh.util.concatenate(pieces))


def test_a_part_added_as_the_docs_say_is_named_in_a_run_report(monkeypatch):
    """docs/relations.md, "Adding a part": a name and a detector in ``PARTS`` (asked after the top's, before the
    others: a step's riser reads as a seat's back), and nothing else. A run on a ground that has one names it, with
    its reason, in the report's parts."""
    def step(found: parts.Found) -> str | None:
        return None if found.highest else f"a step: {found.at}"

    top, *others = parts.PARTS.items()
    monkeypatch.setattr(parts, "PARTS", dict([top, ("step", parts.Part("step", step)), *others]))
    result, _ = _run(stepped_block(), crate(0.1), "a crate on the stepped block", "stepped block", "crate")
    named = export.report(result)["extra"]["parts"]
    assert any(line.startswith("a step: facing up, 0.25 above the bottom") for line in named), named
    assert any(line.startswith("the top: the highest surface, facing up, 0.5") for line in named), named
    monkeypatch.undo()
    found = parts.find_parts.__wrapped__(prepared(stepped_block(), crate(0.1)))
    assert [s.name for s in found.surfaces] == ["top", "seat"]  # without it: a back rises behind the step


def test_parts_name_their_reasons_in_file_units():
    found = parts.find_parts(prepared(dining_chair(), cushion()))
    assert any("0.47 above the bottom" in line for line in found.describe()), found.describe()


def pen_holder() -> trimesh.Trimesh:
    """An open cylinder 0.08 wide and 0.1 tall (its floor 0.005 thick), standing on y = 0: a narrow container."""
    outer = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=32)
    inner = trimesh.creation.cylinder(radius=0.036, height=0.1, sections=32)
    inner.apply_translation([0, 0, 0.005])
    cup = trimesh.boolean.difference([outer, inner])
    cup.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))
    cup.apply_translation([0, 0.05, 0])
    return gltf(cup)


def test_a_pencil_in_a_narrow_pen_holder_goes_in_through_its_opening():
    pencil = trimesh.creation.cylinder(radius=0.004, height=0.18, sections=12)
    pencil.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))
    result, centre = _run(pen_holder(), gltf(pencil), "a pencil in the pen holder", "pen holder", "pencil")
    assert result.relation["holds"], result.relation
    placed = pencil.copy()
    placed.apply_translation([3.0, 0.5, 2.0])
    placed.apply_transform(result.source_to_target)
    low, high = placed.bounds
    # along the holder's axis: its foot inside the cavity, its top out above the rim, nowhere through the wall
    assert np.hypot(centre[0], centre[2]) < 0.03 and low[1] < 0.05 and high[1] > 0.1, placed.bounds
    assert high[1] - low[1] > 0.15, placed.bounds  # standing along the axis, not lying across the mouth
