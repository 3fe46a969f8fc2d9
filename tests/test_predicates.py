"""Relation predicates (``ctp_core.relations.predicates``) on generated pairs whose answer is known.

Every scene is built in its file frame with +Y up and prepared without the upright turn, so "up" is known;
each test places the source at a few touching (or near) alternatives and checks that the relation's score
ranks the intended one first and that it alone holds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from ctp_core.geometry.pose import Poses
from ctp_core.pairs import prepare_pair
from ctp_core.reading.records import RELATIONS
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import attached, measures, predicates
from ctp_core.relations.registry import SPECS


def box(extents, centre) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def table() -> trimesh.Trimesh:
    """A 2 x 2 top (0.1 thick, its upper face at y = 1.05) on four legs standing on y = 0."""
    parts = [box([2, 0.1, 2], [0, 1.0, 0])]
    parts += [box([0.1, 0.95, 0.1], [x, 0.475, z]) for x in (-0.9, 0.9) for z in (-0.9, 0.9)]
    return trimesh.util.concatenate(parts)


def cup() -> trimesh.Trimesh:
    """An open box 0.6 wide, 0.6 high (floor 0.05 thick), standing on y = 0."""
    parts = [box([0.6, 0.05, 0.6], [0, 0.025, 0]), box([0.05, 0.6, 0.6], [-0.275, 0.3, 0]),
             box([0.05, 0.6, 0.6], [0.275, 0.3, 0]), box([0.5, 0.6, 0.05], [0, 0.3, -0.275]),
             box([0.5, 0.6, 0.05], [0, 0.3, 0.275])]
    return trimesh.util.concatenate(parts)


def pose(translation, rotation=None) -> np.ndarray:
    """A source file -> target file 4x4: rotation (3x3, about the source's own origin) then translation."""
    m = np.eye(4)
    if rotation is not None:
        m[:3, :3] = rotation
    m[:3, 3] = translation
    return m


def rot(axis, degrees) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(math.radians(degrees), axis)[:3, :3]


def poses(pair, matrices) -> Poses:
    return Poses.cat([predicates.poses_of(pair.local_to_normalised(m)) for m in matrices])


def prepared(target, source, scale: float = 1.0):
    target, source = target.copy(), source.copy()
    target.apply_scale(scale)
    source.apply_scale(scale)
    return prepare_pair(target, source, samples=1500, seed=0, canonicalise=False)


def reading(name: str | None, figure: bool = True) -> RelationReading | None:
    """The relation as a run passes it (None: no relation)."""
    return None if name is None else RelationReading.parse(name, "figure" if figure else "ground")


def scores(target, source, matrices, relation, figure=True, scale=1.0) -> torch.Tensor:
    pair = prepared(target, source, scale)
    scaled = [np.diag([1, 1, 1, 1.0]) @ m for m in matrices]
    for m in scaled:
        m[:3, 3] *= scale
    return predicates.relation_score(pair, poses(pair, scaled), reading(relation, figure))


BALL = trimesh.creation.icosphere(subdivisions=3, radius=0.2)
# a ball on the table top, under it on the floor, beside it on the floor, and on the top's edge (its centre
# beyond the edge: it would roll off)
BALL_POSES = {"on": pose([0, 1.25, 0]), "under": pose([0, 0.2, 0]), "beside": pose([1.35, 0.2, 0]),
              "edge": pose([1.12, 1.05 + math.sqrt(0.2**2 - 0.12**2), 0])}


@pytest.mark.parametrize("relation", ["on", "under", "beside"])
def test_ball_and_table_each_relation_ranks_its_pose_first(relation):
    names = list(BALL_POSES)
    s = scores(table(), BALL, list(BALL_POSES.values()), relation)
    assert names[int(s.argmin())] == relation, dict(zip(names, s.tolist(), strict=True))
    verdicts = dict(zip(names, predicates.holds(s).tolist(), strict=True))
    assert verdicts[relation] and sum(verdicts.values()) == 1, verdicts


def test_ball_on_the_edge_is_not_on_and_not_stable():
    pair = prepared(table(), BALL)
    p = poses(pair, [BALL_POSES["on"], BALL_POSES["edge"]])
    steady = predicates.holds(predicates.stable(pair, p))
    assert steady.tolist() == [True, False]


def test_stick_in_a_cup_rather_than_beside_it():
    stick = trimesh.creation.cylinder(radius=0.03, height=0.9)  # centred: bottom at -0.45
    alternatives = [pose([0, 0.05 + 0.45, 0]), pose([0.5, 0.45, 0]), pose([0, 0.6 + 0.03, 0], rot([0, 0, 1], 90))]
    s = scores(cup(), stick, alternatives, "in")  # in it, standing beside it, lying across its rim
    assert int(s.argmin()) == 0 and predicates.holds(s).tolist() == [True, False, False], s


def test_cap_worn_on_a_head_rather_than_beside_it():
    head = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    head.apply_translation([0, 0.5, 0])
    cap = trimesh.creation.cone(radius=0.3, height=0.3)  # base on z = 0
    up = rot([1, 0, 0], -90)  # cone axis +Z -> +Y
    alternatives = [pose([0, 0.9, 0], up), pose([1.0, 0.0, 0], up), pose([0.52, 0.5, 0], rot([0, 0, 1], -90) @ up)]
    s = scores(head, cap, alternatives, "wear")  # on the top, on the floor beside it, against its side
    assert int(s.argmin()) == 0 and predicates.holds(s).tolist() == [True, False, False], s


def test_board_leaning_on_a_box_rather_than_lying_flat():
    crate = box([1, 1, 1], [0, 0.5, 0])
    board = box([0.05, 1.2, 0.4], [0, 0, 0])
    tilt = rot([0, 0, 1], 30)  # its top toward the box
    corners = (tilt @ (np.array([[sx * 0.025, sy * 0.6, 0] for sx in (-1, 1) for sy in (-1, 1)]).T)).T
    low, reach = corners[:, 1].min(), corners[:, 0].min()
    leaning = pose([0.5 - reach, -low, 0], tilt)
    flat_floor = pose([0.5 + 0.6, 0.025, 0], rot([0, 0, 1], 90))  # lying on the floor, its end at the box's foot
    flat_top = pose([0, 1.025, 0], rot([0, 0, 1], 90))  # lying on the box
    s = scores(crate, board, [leaning, flat_floor, flat_top], "lean")
    assert int(s.argmin()) == 0 and predicates.holds(s).tolist() == [True, False, False], s
    lie = scores(crate, board, [leaning, flat_floor, flat_top], "lie")
    assert int(lie.argmin()) == 2, lie


def wall_with_peg() -> trimesh.Trimesh:
    """A wall 1 x 1 (0.1 thick, its front face at z = 0) with a peg 0.03 in radius along +z at y = 1."""
    wall = box([1, 1, 0.1], [0, 1.0, -0.05])
    peg = trimesh.creation.cylinder(radius=0.03, height=0.4)  # along z
    peg.apply_translation([0, 1.0, 0.2])
    return trimesh.util.concatenate([wall, peg])


def ring() -> trimesh.Trimesh:
    """A ring in the xy plane, 0.13 inside radius."""
    return trimesh.creation.torus(major_radius=0.15, minor_radius=0.02)


def test_ring_hanging_on_a_hook_rather_than_lying_under_it():
    hook, ring_ = wall_with_peg(), ring()
    hanging = pose([0, 1.0 + 0.03 + 0.02 - 0.15, 0.25])  # its inner top on the peg's top
    under = pose([0, 0.3, 0.25], rot([1, 0, 0], 90))  # lying flat, below the peg, touching nothing
    on_top = pose([0, 1.0 + 0.03 + 0.02, 0.3], rot([1, 0, 0], 90))  # lying on the peg
    s = scores(hook, ring_, [hanging, under, on_top], "hang")
    assert int(s.argmin()) == 0 and predicates.holds(s).tolist() == [True, False, False], s


def test_cup_upright_is_stable_and_tipped_on_its_edge_is_not():
    mug = trimesh.creation.cylinder(radius=0.1, height=0.25)
    mug.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))  # axis +Y
    upright = pose([0, 1.05 + 0.125, 0])
    tip = rot([0, 0, 1], 70)  # resting on one point of its base's rim, its centre past it (tips over past 39°)
    turned = mug.vertices @ tip.T
    corner = turned[turned[:, 1].argmin()]
    tipped = pose([-corner[0], 1.05 - corner[1], 0], tip)
    pair = prepared(table(), mug)
    p = poses(pair, [upright, tipped])
    assert predicates.holds(predicates.stable(pair, p)).tolist() == [True, False]
    on = predicates.relation_score(pair, p, reading("on"))
    assert predicates.holds(on).tolist() == [True, False]


def test_ground_role_reads_the_relation_the_other_way_round():
    """"a table under a vase": the table is the source and the ground; the vase (target) must be on it."""
    vase = trimesh.creation.cylinder(radius=0.15, height=0.5)
    vase.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))
    vase.apply_translation([0, 0.25, 0])  # standing on y = 0 in its file
    below = pose([0, -1.05, 0])  # the table's top under the vase's base
    aside = pose([3.0, 0, 0])  # the table standing beside the vase
    s = scores(vase, table(), [below, aside], "on", figure=False)
    assert predicates.holds(s).tolist() == [True, False], s


@pytest.mark.parametrize("scale", [1e-3, 1e3])
def test_scores_are_scale_free(scale):
    plain = scores(table(), BALL, list(BALL_POSES.values()), "on")
    scaled = scores(table(), BALL, list(BALL_POSES.values()), "on", scale=scale)
    assert predicates.holds(plain).tolist() == predicates.holds(scaled).tolist()
    assert torch.allclose(plain, scaled, rtol=1e-2, atol=1e-3)


@pytest.mark.parametrize("relation", list(SPECS))
def test_batched_equals_one_by_one_and_gradients_are_finite(relation):
    pair = prepared(table(), BALL)
    p = poses(pair, list(BALL_POSES.values()))
    batched = predicates.relation_score(pair, p, reading(relation))
    single = torch.cat([predicates.relation_score(pair, p.select([i]), reading(relation)) for i in range(len(p))])
    assert torch.allclose(batched, single, atol=1e-5)
    leaf = Poses(p.t.clone().requires_grad_(True), p.q.clone().requires_grad_(True),
                 p.log_s.clone().requires_grad_(True))
    total = predicates.relation_score(pair, leaf, reading(relation)).sum() + predicates.stable(pair, leaf).sum()
    total.backward()
    for g in (leaf.t.grad, leaf.q.grad, leaf.log_s.grad):
        assert g is None or torch.isfinite(g).all()


def test_no_relation_has_no_term_and_a_verdict_reports():
    pair = prepared(table(), BALL)
    p = poses(pair, list(BALL_POSES.values()))
    assert predicates.relation_score(pair, p, None).tolist() == [0.0] * 4
    assert predicates.verdict(pair, p.matrices()[0], None) is None
    v = predicates.verdict(pair, p.matrices()[0], reading("on"))
    usual, stands = v.to_dict()["usual"], v.to_dict()["pose"]
    assert {k: x for k, x in v.to_dict().items() if k not in ("usual", "pose")} == {
        "name": "on", "role": "figure", "score": 0.0, "holds": True, "stable": True}
    assert stands.startswith("standing as it is set down"), stands
    assert usual.startswith("the top: the highest surface"), usual  # the table's top, named by the ground's parts


# --- the usual arrangement among poses where the relation holds (``predicates.preference``) ----------------------

def _preference(target, source, matrices, relation) -> tuple[torch.Tensor, torch.Tensor]:
    pair = prepared(target, source)
    p = poses(pair, matrices)
    return predicates.preference(pair, p, reading(relation)), predicates.relation_score(pair, p, reading(relation))


def test_a_cup_on_a_table_prefers_the_middle_of_the_top_to_its_corner():
    mug = trimesh.creation.cylinder(radius=0.1, height=0.25)
    mug.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))  # axis +Y
    middle, corner = pose([0, 1.05 + 0.125, 0]), pose([0.85, 1.05 + 0.125, 0.85])
    prefer, score = _preference(table(), mug, [middle, corner], "on")
    assert predicates.holds(score).tolist() == [True, True], score  # both are "on"
    assert prefer[0] < prefer[1] - 0.3, prefer


def test_a_plate_on_a_table_prefers_lying_flat_to_standing_on_its_rim():
    plate = trimesh.creation.cylinder(radius=0.3, height=0.03)
    plate.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))  # lying: axis +Y
    flat = pose([0, 1.05 + 0.015, 0])
    on_rim = pose([0, 1.05 + 0.3, 0], rot([1, 0, 0], 90))  # its axis horizontal, balanced on its rim, centred
    prefer, score = _preference(table(), plate, [flat, on_rim], "on")
    assert predicates.holds(score)[0], score
    assert prefer[0] < prefer[1] - 0.5, prefer


def test_on_top_of_prefers_the_highest_surface():
    """A small box on a tower's top rather than on its lower step (both hold "on": up-facing, nothing above). One
    solid (a union): the step is a ring round the tower, not a full face under it, and its ring is about as roomy
    for the box as the top."""
    tower = trimesh.boolean.union([box([2, 1, 2], [0, 0.5, 0]), box([0.6, 1, 0.6], [0, 1.5, 0])])
    cube = box([0.2, 0.2, 0.2], [0, 0, 0])
    top, step = pose([0, 2.1, 0]), pose([0.75, 1.1, 0.75])
    prefer, score = _preference(tower, cube, [top, step], "on")
    assert predicates.holds(score).tolist() == [True, True], score
    assert prefer[0] < prefer[1] - 1.0, prefer


def test_a_cross_balanced_on_a_spire_tip_rests_on_it_and_one_touching_its_side_does_not():
    """Support by sideways-facing surface on every side of the contact (a cone's tip); a figure touching one
    side of it with its bottom is pushed sideways, not held up."""
    spire = trimesh.creation.cone(radius=0.3, height=2.0, sections=48)
    spire.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0]))  # tip at y = 2
    cross = box([0.1, 0.3, 0.02], [0, 0, 0])
    on_tip = pose([0, 2.0 - 0.01 + 0.15, 0])  # settled as the search settles: a hair into the sampled tip
    side_x = 0.3 * (1 - 1.0 / 2.0) + 0.05  # the cone's radius at y = 1, plus the cross's half-width
    against_side = pose([side_x + 0.01, 1.0 + 0.15, 0])
    score = scores(spire, cross, [on_tip, against_side], "on")
    assert predicates.holds(score).tolist() == [True, False], score


def test_in_prefers_a_cavity_that_holds_the_figure_by_its_sides_to_an_open_frame():
    """Within a frame of four posts (inside its convex hull, below its top: "in" holds) a stick is not held by
    anything around its foot; in the cup on the frame's top it is."""
    posts = [box([0.05, 1.0, 0.05], [x, 0.5, z]) for x in (-0.3, 0.3) for z in (-0.3, 0.3)]
    holder = cup()
    holder.apply_translation([0, 1.0, 0])
    boards = [box([0.7, 0.02, 0.7], [0, y, 0]) for y in (0.01, 0.99)]
    stand = trimesh.util.concatenate([*posts, *boards, holder])
    stick = trimesh.creation.cylinder(radius=0.03, height=0.5)  # along z
    upright = rot([1, 0, 0], -90)
    in_cup, in_frame = pose([0, 1.05 + 0.25, 0], upright), pose([0.1, 0.02 + 0.25, 0.1], upright)  # on a board
    prefer, score = _preference(stand, stick, [in_cup, in_frame], "in")
    assert predicates.holds(score).tolist() == [True, True], score
    assert prefer[0] < prefer[1] - 0.3, prefer


def test_a_ring_on_a_peg_prefers_hanging_freely_to_swung_aside_stuck_under_the_wall_or_flat_against_it():
    """All four hold "hang" (contact above the centre); the usual arrangement rests on what bears it, plumb."""
    swing = math.radians(40)  # the peg touches the ring's inside 40 degrees off its top: the centre not below it
    threaded = pose([0, 0.9, 0.25])
    swung = pose([0.1 * math.sin(swing), 1.0 - 0.1 * math.cos(swing), 0.25])
    flat = pose([0.3, 0.9, 0.02])  # against the wall's front, beside the peg: its contact above is a side
    stuck = pose([0.3, 0.5 - 0.17, -0.05])  # its top against the wall's underside (y = 0.5): held by nothing seen
    prefer, score = _preference(wall_with_peg(), ring(), [threaded, swung, flat, stuck], "hang")
    assert predicates.holds(score).tolist() == [True, True, True, True], score
    # threaded: on the peg (a bar, ``relations.thin``) a quarter of its half-length out from its middle, hung plumb
    assert abs(prefer[0] - measures.OFF_CENTRE * 0.25) < 0.08, prefer
    assert prefer[0] + 0.05 < prefer[1] < prefer[3] < prefer[2] == measures.FAR, prefer
    assert prefer[3] >= attached.FIXED, prefer


def test_preference_is_zero_where_the_relation_says_nothing_more_and_batched_equals_one_by_one():
    pair = prepared(table(), BALL)
    p = poses(pair, list(BALL_POSES.values()))
    for relation in ("attach", "hold", None):
        assert predicates.preference(pair, p, reading(relation)).tolist() == [0.0] * 4
    for relation in ("on", "in", "under", "lean", "wear", "hang", "penetrate", "beside", "front"):
        batched = predicates.preference(pair, p, reading(relation))
        single = torch.cat([predicates.preference(pair, p.select([i]), reading(relation)) for i in range(len(p))])
        assert torch.allclose(batched, single, atol=1e-5), relation


@pytest.mark.parametrize("relation", [*SPECS, None])
def test_terms_equal_the_predicates_one_by_one(relation):
    """``terms`` (what the objective reads, one support footprint per pose) equals the public predicates."""
    pair = prepared(table(), BALL)
    p = poses(pair, list(BALL_POSES.values()))
    got = predicates.terms(pair, p, reading(relation))
    assert torch.allclose(got.rel, predicates.relation_score(pair, p, reading(relation)))
    assert torch.allclose(got.prefer, predicates.preference(pair, p, reading(relation)))
    own = relation is not None and RELATIONS[relation].steady and not RELATIONS[relation].rests
    assert torch.allclose(got.stable, predicates.stable(pair, p) if own else torch.zeros(len(p)))


def test_a_stick_stuck_into_a_block_prefers_standing_in_its_top_to_lying_sunk_along_it_or_rising_through_its_base():
    block, stick = box([0.3, 0.3, 0.3], [0, 0.15, 0]), trimesh.creation.cylinder(radius=0.015, height=0.8)  # along z
    upright = rot([1, 0, 0], -90)  # the stick's axis +z -> +y
    into_top = pose([0, 0.3 + 0.4 - 0.1, 0], upright)  # 0.1 of it in, through the top's middle
    lying = pose([0, 0.3, 0])  # along z, half sunk in the top along its whole width
    through_base = pose([0, 0.1 - 0.4, 0], upright)  # 0.1 in, through the base: most of it under the floor
    prefer, score = _preference(block, stick, [into_top, lying, through_base], "penetrate")
    assert predicates.holds(score).tolist() == [True, True, True], score
    assert prefer[0] < 0.1 and prefer[0] + 0.5 < prefer[1] and prefer[0] + 0.5 < prefer[2], prefer


# "on" must mean above: a ground thin against the figure (a plate, a board, a sheet) is support from one side only,
# the side its up-facing surface faces. (thickness, figure radius): a plate, a board, a sheet.
THIN_GROUNDS = [(0.05, 0.3), (0.2, 1.0), (0.01, 0.5)]


@pytest.mark.parametrize(("thickness", "radius"), THIN_GROUNDS)
@pytest.mark.parametrize("relation", ["on", "stand", "sit", "lie"])
def test_resting_on_a_thin_ground_needs_the_figure_above_it(thickness, radius, relation):
    ground = box([3, thickness, 3], [0, 0, 0])
    ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    top, bottom = thickness / 2 + radius, -(thickness / 2 + radius)
    pair = prepared(ground, ball)
    s = predicates.relation_score(pair, poses(pair, [pose([0, top, 0]), pose([0, bottom, 0])]), reading(relation))
    assert predicates.holds(s).tolist() == [True, False], s
    verdicts = [predicates.verdict(pair, pair.local_to_normalised(pose([0, y, 0])), reading(relation))
                for y in (top, bottom)]
    assert [v.holds for v in verdicts] == [True, False], verdicts
