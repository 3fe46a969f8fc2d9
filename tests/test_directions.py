"""The directional relations (``predicates``: sides, above/below, near/far, orientations) on generated pairs whose
answer is known.

Scenes are built in their file frame with +Y up and the glTF front (+Z), prepared without the upright turn; the
fronts come through ``PreparedPair.target_front`` / ``front_trusted`` / ``source_front``: stated here for the
predicates (``prepared``), from the file's convention for whole runs (the meshes are marked as read from GLB).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from test_predicates import box, pose, poses, reading, rot, table
from test_predicates import prepared as prepared_plain

from ctp_core import align as stages
from ctp_core import contact
from ctp_core.align import align
from ctp_core.config import AlignConfig
from ctp_core.geometry.pose import Poses, apply_pose
from ctp_core.pairs import prepare_pair
from ctp_core.relations import apart, attached, builders, measures, predicates
from ctp_core.relations.registry import SPECS
from ctp_core.search import proposals


def gltf(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """``mesh`` as if read from a GLB (``io`` records the format): glTF's convention gives +Y up and front +Z."""
    mesh.metadata["file_format"] = "glb"
    return mesh


def prepared(target, source, scale: float = 1.0):
    """A pair with the glTF fronts stated: the target's front +Z, trusted; the source's front +Z."""
    pair = prepared_plain(target, source, scale)
    pair.target_front, pair.front_trusted = np.array([0.0, 0.0, 1.0]), True
    pair.source_front = np.array([0.0, 0.0, 1.0])
    return pair


def sofa() -> trimesh.Trimesh:
    """A sofa-like block facing +Z: a seat 2 wide (x), 0.9 deep (z), 0.45 high, its backrest along -Z up to 0.9."""
    return gltf(trimesh.util.concatenate([box([2, 0.45, 0.9], [0, 0.225, 0]),
                                          box([2, 0.45, 0.2], [0, 0.675, -0.35])]))


def chair() -> trimesh.Trimesh:
    """A chair-like block facing +Z (its back along -Z), 0.5 wide, standing on y = 0 in its file, centred."""
    return gltf(trimesh.util.concatenate([box([0.5, 0.45, 0.5], [0, -0.2, 0]),
                                          box([0.5, 0.5, 0.08], [0, 0.27, -0.21])]))


def desk() -> trimesh.Trimesh:
    """A desk-like block facing +Z: 1.4 wide, 0.7 deep, 0.75 high, a shelf along its back edge (not symmetric)."""
    return gltf(trimesh.util.concatenate([box([1.4, 0.75, 0.7], [0, 0.375, 0]),
                                          box([1.4, 0.3, 0.15], [0, 0.9, -0.275])]))


BOX = box([0.5, 0.5, 0.5], [0, 0, 0])  # centred: on the floor at y = 0.25
ON_FLOOR = 0.25
SIDE_POSES = {"left": pose([1.6, ON_FLOOR, 0]), "right": pose([-1.6, ON_FLOOR, 0]),
              "front": pose([0, ON_FLOOR, 1.1]), "behind": pose([0, ON_FLOOR, -1.1])}


def _holding(pair, matrices, relation) -> list[bool]:
    return predicates.holds(predicates.relation_score(pair, poses(pair, matrices), reading(relation))).tolist()


@pytest.mark.parametrize("side", list(SIDE_POSES))
def test_each_side_of_a_sofa_holds_where_the_box_is_in_the_sofas_own_frame(side):
    """glTF: front +Z, up +Y, so the object's own left is +X (up x front): a box at +X is on the sofa's left."""
    pair = prepared(sofa(), BOX)
    held = dict(zip(SIDE_POSES, _holding(pair, list(SIDE_POSES.values()), side), strict=True))
    assert held == {s: s == side for s in SIDE_POSES}, held


def test_a_box_level_with_the_sofas_end_but_well_in_front_of_it_is_in_front_not_left():
    pair = prepared(sofa(), BOX)
    corner = [pose([1.2, ON_FLOOR, 0.9])]  # beyond the left end by 0.2, beyond the front by 0.45
    assert _holding(pair, corner, "front") == [True] and _holding(pair, corner, "left") == [False]


def test_the_sides_turn_with_the_targets_front():
    """The same sofa turned to face +X (its front in the normalised frame): its left is then -Z."""
    pair = prepared(sofa(), BOX)
    pair.target_front = np.array([1.0, 0.0, 0.0])
    assert _holding(pair, [pose([0, ON_FLOOR, -1.1]), pose([0, ON_FLOOR, 1.1])], "left") == [True, False]


def test_an_untrusted_front_judges_the_sides_in_the_viewers_frame():
    """No front to trust: the preview's first camera (azimuth 30 degrees, on the +Z side) is the viewer; the sofa
    faces it, so the sofa's own right (-X) is the viewer's left, and the report says so."""
    pair = prepared(sofa(), BOX)
    matrices = [SIDE_POSES["right"], SIDE_POSES["left"]]
    assert _holding(pair, matrices, "left") == [False, True]
    pair.front_trusted = False
    assert _holding(pair, matrices, "left") == [True, False]
    verdict = predicates.verdict(pair, poses(pair, matrices[:1]).matrices()[0], reading("left"))
    assert verdict.to_dict()["frame"] == "viewer" and verdict.side == "left" and verdict.holds


def test_beside_on_a_side_must_stand_near_it():
    pair = prepared(sofa(), BOX)
    assert _holding(pair, [pose([5.0, ON_FLOOR, 0]), pose([1.6, 1.5, 0])], "left") == [False, False]  # far; in the air


PICTURE = box([0.8, 0.6, 0.05], [0, 0, 0])


def test_a_picture_above_a_table_without_touching_it_and_not_beside_it():
    pair = prepared(table(), PICTURE)
    above = pose([0, 1.6, -0.95])  # over the table's back edge, 0.25 clear of its top (1.05)
    resting = pose([0, 1.05 + 0.3, 0])  # standing on the top: contact, "on"
    aside = pose([2.0, 1.6, 0])  # as high, but beside the table
    assert _holding(pair, [above, resting, aside], "above") == [True, False, False]


def test_a_ball_below_a_hanging_lamp_and_not_above_it():
    lamp = box([0.6, 0.2, 0.6], [0, 2.0, 0])
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    pair = prepared(lamp, ball)
    below, over = pose([0, 1.0, 0.1]), pose([0, 2.5, 0])
    assert _holding(pair, [below, over], "below") == [True, False]
    assert _holding(pair, [below, over], "above") == [False, True]


def test_near_and_far_are_bands_in_the_objects_mean_diagonal():
    """Sofa diagonal 2.39, box 0.87: mean 1.63; near within 1 (1.63), far beyond 2 (3.26) of that."""
    pair = prepared(sofa(), BOX)
    matrices = [pose([1.6, ON_FLOOR, 0]), pose([1.0 + 0.25 + 2.5, ON_FLOOR, 0]), pose([1.0 + 0.25 + 4.0, ON_FLOOR, 0])]
    assert _holding(pair, matrices, "near") == [True, False, False]
    assert _holding(pair, matrices, "far") == [False, False, True]


DESK = desk()
CHAIR_AT = [0, 0.425, 1.0]  # in front of the desk, on the floor (the chair's file origin 0.425 above its feet)


def test_a_chair_facing_the_desk_facing_away_or_turned_aside():
    pair = prepared(DESK, chair())
    turned = {"toward": rot([0, 1, 0], 180), "away": np.eye(3), "aside": rot([0, 1, 0], 90)}
    matrices = [pose(CHAIR_AT, r) for r in turned.values()]
    assert _holding(pair, matrices, "facing") == [True, False, False]
    assert _holding(pair, matrices, "facing_away") == [False, True, False]
    assert _holding(pair, matrices, "aligned") == [False, True, False]  # its front the desk's way: +Z


def test_a_reading_of_two_relations_holds_when_both_do_and_the_verdict_says_each():
    pair = prepared(DESK, chair())
    facing, away = pose(CHAIR_AT, rot([0, 1, 0], 180)), pose(CHAIR_AT)
    assert _holding(pair, [facing, away], "front+facing") == [True, False]
    verdict = predicates.verdict(pair, poses(pair, [away]).matrices()[0], reading("front+facing")).to_dict()
    assert verdict["side"] == "front" and verdict["frame"] == "target" and not verdict["holds"]
    assert [(p["name"], p["holds"]) for p in verdict["each"]] == [("front", True), ("facing", False)]
    assert verdict["stable"]


def test_the_source_front_turns_with_the_pose():
    """A chair whose file front is +X (``source_front``) faces the desk (-Z from it) turned by +90 degrees about +Y,
    not by 180 (its front then -X) nor by -90 (+Z: away)."""
    pair = prepared(DESK, chair())
    pair.source_front = np.array([1.0, 0.0, 0.0])
    matrices = [pose(CHAIR_AT, rot([0, 1, 0], angle)) for angle in (90, 180, -90)]
    assert _holding(pair, matrices, "facing") == [True, False, False]


@pytest.mark.parametrize("relation", ["left", "above", "near", "far", "facing", "front+facing"])
def test_directional_scores_are_scale_free(relation):
    matrices = [pose([1.6, ON_FLOOR, 0]), pose([0.5, 1.6, 0.4], rot([0, 1, 0], 90)), pose([0, ON_FLOOR, 2.0])]
    plain = predicates.relation_score(prepared(sofa(), BOX), poses(prepared(sofa(), BOX), matrices), reading(relation))
    for scale in (1e-3, 1e3):
        pair = prepared(sofa(), BOX, scale)
        scaled = [m.copy() for m in matrices]
        for m in scaled:
            m[:3, 3] *= scale
        score = predicates.relation_score(pair, poses(pair, scaled), reading(relation))
        assert torch.allclose(plain, score, rtol=1e-2, atol=1e-3), (plain, score)


def test_a_contact_relations_verdict_keeps_its_shape():
    pair = prepared(table(), BOX)
    verdict = predicates.verdict(pair, poses(pair, [pose([0, 1.3, 0])]).matrices()[0], reading("on")).to_dict()
    assert set(verdict) == {"name", "role", "score", "holds", "stable", "usual", "pose"}
    assert verdict["pose"].startswith("standing as it is set down"), verdict["pose"]
    assert verdict["usual"].startswith("the top: the highest surface"), verdict["usual"]  # the ground's part named


# --- whole runs: geometry only (``lambda_clip`` 0, the ``test`` preset, as ``--no-guidance``) -------------------

def _wall_and_table() -> trimesh.Scene:
    """A 2 x 2 table (top at 1.05) against a wall along its back (-Z) edge: the picture's ground is the table."""
    scene = trimesh.Scene()
    scene.add_geometry(table(), node_name="table", geom_name="table")
    scene.add_geometry(box([3, 2.5, 0.1], [0, 1.25, -1.05]), node_name="wall", geom_name="wall")
    return scene


def _run(target, source, prompt, target_name, source_name, **kwargs):
    config = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0}, upright=False)
    return align(target, source, prompt, config, target_name=target_name, source_name=source_name, **kwargs)


def _posed(result, mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    return mesh.copy().apply_transform(result.source_to_target)


def test_a_box_to_the_left_of_a_sofa_ends_on_its_own_left():
    result = _run(sofa(), BOX, "a box to the left of the sofa", "sofa", "box")
    verdict = result.relation
    assert verdict["name"] == "left" and verdict["side"] == "left" and verdict["frame"] == "target", verdict
    assert verdict["holds"] and verdict["stable"], verdict
    placed = _posed(result, BOX)
    assert placed.bounds[0, 0] > 1.0 - 1e-3 and abs(placed.bounds[0, 1]) < 0.02  # beyond its +X end, on the floor


def test_a_picture_above_a_table_against_a_wall_ends_clear_over_the_table():
    result = _run(_wall_and_table(), PICTURE, "a picture above the table", "table", "picture", on="table")
    verdict = result.relation
    assert verdict["name"] == "above" and verdict["holds"], verdict
    placed = _posed(result, PICTURE)
    centre = placed.bounds.mean(0)
    assert placed.bounds[0, 1] > 1.05 and abs(centre[0]) < 1.0 and -1.0 < centre[2] < 1.0, placed.bounds


def test_a_chair_in_front_of_a_desk_facing_it_ends_there_turned_to_it():
    result = _run(DESK, chair(), "a chair in front of the desk, facing it", "desk", "chair")
    verdict = result.relation
    assert verdict["name"] == "front+facing" and verdict["side"] == "front" and verdict["holds"], verdict
    assert [p["holds"] for p in verdict["each"]] == [True, True], verdict
    placed = _posed(result, chair())
    front = result.source_to_target[:3, :3] @ np.array([0.0, 0.0, 1.0])  # the chair's file front, turned
    assert placed.bounds.mean(0)[2] > 0.35 and front[2] < -np.cos(np.radians(45)), (placed.bounds, front)


def test_a_box_far_from_the_sofa_and_one_near_it():
    far = _posed(_run(sofa(), BOX, "a box far from the sofa", "sofa", "box"), BOX)
    near = _run(sofa(), BOX, "a box near the sofa", "sofa", "box")
    assert near.relation["holds"] and near.relation["name"] == "near", near.relation
    gap = lambda placed: trimesh.proximity.closest_point(sofa(), placed.vertices)[1].min()  # noqa: E731
    assert gap(far) > 2 * 1.62 > 1.62 > gap(_posed(near, BOX)), (gap(far), gap(_posed(near, BOX)))


def test_directional_proposals_hold_their_relation_and_replace_as_many_region_proposals():
    counts = {}
    for relation in (True, False):
        config = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0}, upright=False, relation=relation)
        run = stages.prepare(sofa(), BOX, "a box behind the sofa", config, target_name="sofa", source_name="box")
        props = stages.propose(run)
        made = torch.tensor([r == "behind" for r in props.region])
        assert bool(made.any()) == relation
        if relation:
            with torch.inference_mode():
                held = predicates.holds(predicates.relation_score(run.pair, props.poses, reading("behind")))
            assert held[made].float().mean() > 0.9 and held[made].sum() > held[~made].sum(), held
        counts[relation] = len(props.region)
    assert counts[True] == counts[False], counts


def test_a_chair_lying_on_its_back_faces_nothing():
    """Its front (+Z in its file) turned to point up, a hair toward the desk: no orientation holds."""
    pair = prepared(DESK, chair())
    on_its_back = pose([0, 0.3, 1.0], rot([0, 1, 0], 180) @ rot([1, 0, 0], -85))
    for relation in ("facing", "facing_away", "aligned"):
        assert _holding(pair, [on_its_back], relation) == [False], relation


# --- the gaps: below with its proposals, an orientation alone, a lean on a named side, what holds an "above" up ----

def shelf_unit() -> trimesh.Trimesh:
    """Two uprights 1.6 high standing on y = 0, 1.2 apart, and a shelf board between them at mid-height (y 0.8)."""
    return gltf(trimesh.util.concatenate([box([0.05, 1.6, 0.4], [x, 0.8, 0]) for x in (-0.6, 0.6)]
                                         + [box([1.15, 0.04, 0.4], [0, 0.8, 0])]))


def hung_lamp() -> trimesh.Scene:
    """A wall standing on the floor (y = 0), a ceiling plate on it, and a lamp block hung by a cord from the plate,
    its underside at 2.0: the lamp is the ground (``on``), the floor the scene's lowest level (the wall's foot)."""
    scene = trimesh.Scene()
    scene.add_geometry(box([4, 3.2, 0.1], [0, 1.6, -1.5]), node_name="wall", geom_name="wall")
    scene.add_geometry(box([1, 0.05, 3], [0, 3.025, 0]), node_name="ceiling", geom_name="ceiling")
    lamp = trimesh.util.concatenate([box([0.6, 0.3, 0.6], [0, 2.15, 0]), box([0.02, 0.7, 0.02], [0, 2.65, 0])])
    scene.add_geometry(lamp, node_name="lamp", geom_name="lamp")
    return scene


SMALL_BOX = box([0.3, 0.3, 0.3], [0, 0, 0])  # centred: on the floor at y = 0.15


def test_below_holds_under_a_lifted_shelf_board_and_not_on_it_beside_it_or_under_a_block_on_the_floor():
    """Under the board between the uprights the ground over the box is the board alone: below it, though the unit
    stands on the floor (Sr3D's "under the ground's bottom" could never hold there)."""
    pair = prepared(shelf_unit(), SMALL_BOX)
    under, on_board, beside = pose([0, 0.15, 0]), pose([0, 0.97, 0]), pose([1.2, 0.15, 0])
    assert _holding(pair, [under, on_board, beside], "below") == [True, False, False]
    block = prepared(box([1, 1, 1], [0, 0.5, 0]), SMALL_BOX)  # nothing lifted over the floor: no room below it
    assert _holding(block, [pose([0.66, 0.15, 0]), pose([0, 0.15, 0])], "below") == [False, False]


def _below_proposals(pair) -> tuple[list[str], torch.Tensor, trimesh.Trimesh]:
    config = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0}, search={"candidates": 48})
    rotations = proposals.orientations(pair, config, torch.Generator().manual_seed(0))
    one = contact.Proposals(Poses(torch.zeros(1, 3), torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.zeros(1)),
                                     ["top"], None, rotations, contact.contact_index(pair, seed=0))
    made = SPECS["below"].builder(pair, one, 0, reading("below"), 0.0,
                                                builders.own_count(config))
    with torch.inference_mode():
        held = predicates.holds(predicates.relation_score(pair, made.poses, reading("below")))
    return made.region, held, made


@pytest.mark.parametrize("where", ["shelf", "lamp"])
def test_below_proposals_stand_the_box_on_the_floor_under_a_lifted_part(where):
    pair = (prepared(shelf_unit(), SMALL_BOX) if where == "shelf"
            else prepare_pair(hung_lamp(), SMALL_BOX, samples=1500, seed=0, canonicalise=False, on="lamp"))
    region, held, made = _below_proposals(pair)
    assert set(region) == {"below"} and len(region) >= 6 and held.float().mean() >= 0.75, held
    bottoms = apply_pose(measures.features(pair).source_points, made.poses.t, made.poses.q,
                         made.poses.log_s)[..., 1].min(1).values
    assert torch.allclose(bottoms, torch.full_like(bottoms, pair.floor), atol=0.02 * pair.target_radius), bottoms


def test_no_below_proposals_where_nothing_is_lifted_off_the_floor():
    pair = prepared(box([1, 1, 1], [0, 0.5, 0]), SMALL_BOX)
    config = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0})
    base = proposals.propose(pair, config, proposals.region_weights(None), 0.0,
                                    torch.Generator().manual_seed(0))
    count = builders.own_count(config)
    assert apart.beneath(pair, base, 0, reading("below"), 0.0, count) is None
    assert builders.extend(pair, config, base, reading("below"), 0) is base


def test_an_orientation_said_alone_stands_near_its_ground():
    """ "a chair facing the desk": near+facing. Facing it from across the room does not hold; its verdict says
    both parts."""
    assert reading("facing").name == "near+facing" and reading("facing_away").position == "near"
    assert reading("front+facing").name == "front+facing" and reading("far+facing").name == "far+facing"
    pair = prepared(DESK, chair())
    toward = rot([0, 1, 0], 180)
    close, across_the_room = pose(CHAIR_AT, toward), pose([0, 0.425, 6.0], toward)
    assert _holding(pair, [close, across_the_room], "facing") == [True, False]
    verdict = predicates.verdict(pair, poses(pair, [across_the_room]).matrices()[0], reading("facing")).to_dict()
    assert [(p["name"], p["holds"]) for p in verdict["each"]] == [("near", False), ("facing", True)], verdict


def test_a_chair_facing_the_desk_ends_near_it_turned_to_it():
    result = _run(DESK, chair(), "a chair facing the desk", "desk", "chair")
    assert result.relation["name"] == "near+facing" and result.relation["holds"], result.relation
    placed = _posed(result, chair())
    gap = trimesh.proximity.closest_point(DESK, placed.vertices)[1].min()
    front = result.source_to_target[:3, :3] @ np.array([0.0, 0.0, 1.0])
    toward = (DESK.bounds.mean(0) - placed.bounds.mean(0)) * [1, 0, 1]
    assert gap < 1.3 and front @ toward / np.linalg.norm(toward) > np.cos(np.radians(45)), (gap, front, toward)


BOARD = box([0.6, 0.4, 0.04], [0, 0, 0])  # a board standing on its 0.6 edge, 0.4 high: lower than the seat


def _leaning(side: float) -> np.ndarray:
    """The board tilted 20 degrees toward the sofa, its foot on the floor ``side`` of it (+1 front, -1 back), its
    top edge (the part nearest the sofa: the board is lower than the seat) on the sofa's face that way (the back at
    z -0.45, the seat's front at z 0.45)."""
    tilt = rot([1, 0, 0], -side * 20)
    bounds = BOARD.copy().apply_transform(pose([0, 0, 0], tilt)).bounds
    return pose([0, -bounds[0, 1], side * 0.45 - (bounds[1, 2] if side < 0 else bounds[0, 2])], tilt)


def test_a_lean_on_a_named_side_holds_only_there():
    """Leaning on the backrest's back is lean+behind, not lean+front; leaning on the seat's front is lean+front."""
    pair = prepared(sofa(), BOARD)
    on_back, on_front = _leaning(-1), _leaning(1)
    assert _holding(pair, [on_back, on_front], "lean") == [True, True]
    assert _holding(pair, [on_back, on_front], "lean+behind") == [True, False]
    assert _holding(pair, [on_back, on_front], "lean+front") == [False, True]
    verdict = predicates.verdict(pair, poses(pair, [on_back]).matrices()[0], reading("lean+behind")).to_dict()
    assert verdict["side"] == "behind" and verdict["frame"] == "target" and verdict["stable"], verdict


def test_lean_proposals_on_a_named_side_lean_on_that_side():
    pair = prepared(sofa(), BOARD)
    config = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0}, search={"candidates": 48})
    base = proposals.propose(pair, config, proposals.region_weights(None), 0.0,
                                    torch.Generator().manual_seed(0))
    made = attached.lean(pair, base, 0, reading("lean+behind"), 0.0, builders.own_count(config))
    centres = apply_pose(measures.features(pair).source_centre[None], made.poses.t, made.poses.q,
                         made.poses.log_s)[:, 0]
    assert bool((centres[:, 2] < -0.45).all()), centres  # all behind the backrest (the sofa faces +Z)
    with torch.inference_mode():
        held = predicates.holds(predicates.relation_score(pair, made.poses, reading("lean+behind")))
    assert held.float().mean() >= 0.5, held


def test_above_asks_no_support_and_the_verdict_says_nothing_holds_it_up():
    """A picture clear above a table touches nothing of the pair: its verdict has no ``stable`` and a note saying
    what is not modelled; a box standing under a shelf board, or a cup on a table, has no note."""
    pair = prepared(table(), PICTURE)
    above = predicates.verdict(pair, poses(pair, [pose([0, 1.6, -0.95])]).matrices()[0], reading("above")).to_dict()
    assert above["holds"] and above["stable"] is None and above["note"] == predicates.UNHELD, above
    shelf = prepared(shelf_unit(), SMALL_BOX)
    below = predicates.verdict(shelf, poses(shelf, [pose([0, 0.15, 0])]).matrices()[0], reading("below")).to_dict()
    assert below["holds"] and "note" not in below, below
    on = predicates.verdict(pair, poses(pair, [pose([0, 1.35, 0])]).matrices()[0], reading("on")).to_dict()
    assert "note" not in on, on


def test_a_box_below_a_hung_lamp_ends_on_the_floor_under_it():
    result = _run(hung_lamp(), SMALL_BOX, "a box below the lamp", "lamp", "box", on="lamp")
    assert result.relation["name"] == "below" and result.relation["holds"], result.relation
    placed = _posed(result, SMALL_BOX)
    centre = placed.bounds.mean(0)
    assert abs(placed.bounds[0, 1]) < 0.02 and np.hypot(centre[0], centre[2]) < 0.3 + 0.22, placed.bounds


def test_a_board_against_the_back_of_the_sofa_leans_on_its_back():
    result = _run(sofa(), BOARD, "a board against the back of the sofa", "sofa", "board")
    verdict = result.relation
    assert verdict["name"] == "lean+behind" and verdict["side"] == "behind" and verdict["holds"], verdict
    placed = _posed(result, BOARD)
    assert placed.bounds.mean(0)[2] < -0.45 and placed.bounds[0, 1] > -0.02, placed.bounds  # behind the back
