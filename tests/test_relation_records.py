"""A relation is one record (``records.RELATIONS``) and one spec (``registry.SPECS``: its judge, and a builder of
its own proposals where the regions do not reach it); the relation a run uses is
one value (``RelationReading``). The relation proposals are tested one by one on small generated meshes: what they
make satisfies the relation's score, as many as their share of the search."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from test_predicates import BALL, BALL_POSES, box, cup, poses, prepared, ring, table, wall_with_peg

from ctp_core import contact
from ctp_core.align import align
from ctp_core.config import AlignConfig
from ctp_core.geometry.pose import Poses
from ctp_core.priors import get_provider
from ctp_core.priors.prior import ScenePrior
from ctp_core.reading import cues, records
from ctp_core.reading.cues import Cue
from ctp_core.reading.records import RELATIONS, Relation
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import apart, attached, builders, predicates, registry, resting
from ctp_core.relations.registry import SPECS
from ctp_core.relations.spec import Judge, Spec
from ctp_core.search import proposals

CONFIG = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0}, search={"candidates": 48})
# each builder's count: what it makes, less those that settling leaves wedged in the target
SHARE = builders.own_count(CONFIG)


# --- one record, one judge -----------------------------------------------------------------------------------------

def test_every_relation_has_one_record_and_one_judge_and_builders_are_for_relations_only():
    assert not records.check() and not registry.check(SPECS)
    assert set(SPECS) == set(RELATIONS)
    assert all(record.name == name for name, record in RELATIONS.items())
    assert not registry.check(SPECS)
    assert all(set(r.figure_regions) | set(r.ground_regions) <= set(proposals.REGIONS) for r in RELATIONS.values())
    # the resting family shares one judge, and only it includes stability in its score
    family = {name for name, r in RELATIONS.items() if r.rests}
    assert family == {"on", "stand", "sit", "lie"}
    assert {name for name, s in SPECS.items() if s.judge.score is resting.score_resting} == family
    assert all(RELATIONS[name].steady for name in family)


def test_the_directional_kinds_weigh_the_regions_as_beside_does_in_either_role():
    for name, record in RELATIONS.items():
        for figure in (True, False):
            role = "figure" if figure else "ground"
            weights = proposals.region_weights(RelationReading.parse(name, role))
            if record.kind in ("side", "distance", "orientation"):
                assert weights == proposals.region_weights(RelationReading.parse("beside", role)), name
    plain = proposals.region_weights(None)
    assert set(plain.values()) == {1.0}
    assert proposals.region_weights(RelationReading.parse("on", "ground"))["bottom"] == 4.0
    assert proposals.region_weights(RelationReading.parse("front+facing")) == proposals.region_weights(
        RelationReading.parse("front"))  # a reading of two: its position's


def test_adding_a_relation_is_its_record_and_its_judge(monkeypatch):
    """A throwaway relation registered in the two tables is read, weighted, scored, judged and reported by every
    derived function with nothing else changed."""
    record = Relation("hover", 0.0, 0.0, 0.5, kind="vertical", figure_regions={"drop": 5.0})
    monkeypatch.setitem(RELATIONS, "hover", record)
    monkeypatch.setitem(SPECS, "hover", Spec("hover", Judge(apart.score_above)))
    reading = RelationReading.parse("hover")
    assert not reading.steady and not reading.rests and reading.side is None
    assert proposals.region_weights(reading)["drop"] == 5.0
    pair = prepared(table(), BALL)
    p = poses(pair, list(BALL_POSES.values()))
    assert torch.equal(predicates.relation_score(pair, p, reading),
                       predicates.relation_score(pair, p, RelationReading.parse("above")))
    assert predicates.terms(pair, p, reading).stable.tolist() == [0.0] * len(p)
    verdict = predicates.verdict(pair, p.matrices()[0], reading).to_dict()
    assert verdict["name"] == "hover" and verdict["stable"] is None
    # a steady one: stability joins its terms (not resting: its score does not include it)
    monkeypatch.setitem(RELATIONS, "hover", replace(record, steady=True))
    assert torch.allclose(predicates.terms(pair, p, reading).stable, predicates.stable(pair, p))



def test_a_relation_added_as_the_docs_say_runs_end_to_end(monkeypatch):
    """A one-ground relation added where docs/relations.md ("Adding a relation") says, and nowhere else: a record
    and a wording in ``reading`` (``records``, ``cues``), a spec in the registry. A whole run reads it from the
    prompt, searches, judges and reports it."""
    record = Relation("teeter", 0.05, 0.02, 0.3, rests=True, steady=True, figure_regions={"top": 4.0, "drop": 4.0})
    monkeypatch.setitem(RELATIONS, "teeter", record)
    monkeypatch.setattr(cues, "CUES", [Cue(r"teeter(?:s|ing)? on", "teeter"), *cues.CUES])
    monkeypatch.setitem(SPECS, "teeter", Spec("teeter", resting.SPECS["on"].judge, usual="on the top"))
    assert not registry.check(SPECS)
    prompt = "a ball teetering on the table"
    assert get_provider("rules").estimate("table", "ball", prompt).reading.name == "teeter"
    ball = BALL.copy()
    ball.apply_translation([3.0, 0.5, 2.0])
    config = AlignConfig.from_preset("test").merged({"loss": {"lambda_clip": 0.0}})
    result = align(table(), ball, prompt, config, target_name="table", source_name="ball")
    assert result.relation["name"] == "teeter" and result.relation["holds"], result.relation
    monkeypatch.undo()
    assert get_provider("rules").estimate("table", "ball", prompt).reading.name != "teeter"



def test_docs_relations_lists_every_specs_usual_place():
    """docs/relations.md's usual-place table is the registry's: each spec's ``usual`` and whether its preference
    ranks toward it, with relations that share both on one row."""
    rows = {}
    for name, spec in SPECS.items():
        rows.setdefault((spec.usual, spec.judge.preference is not None), []).append(name)
    expected = [f"| {', '.join(names)} | {usual} | {'yes' if ranked else 'no: wherever it holds'} |"
                for (usual, ranked), names in rows.items()]
    assert all(spec.usual for spec in SPECS.values())
    docs = (Path(__file__).resolve().parents[1] / "docs" / "relations.md").read_text().splitlines()
    start = docs.index("| relations | usual place | ranked toward it |") + 2
    assert docs[start:start + len(expected) + 1] == [*expected, ""]


# --- the reading ---------------------------------------------------------------------------------------------------

def test_a_reading_of_two_names_its_position_side_and_orientation():
    r = RelationReading.parse("front+facing")
    assert (r.relations, r.position, r.side, r.orientation, r.role) == (("front", "facing"), "front", "front",
                                                                          "facing", "figure")
    assert r.name == "front+facing" and r.steady and not r.rests and r.directional
    assert [x.name for x in r.records] == ["front", "facing"]
    on = RelationReading.parse("on", "ground")
    assert on.rests and on.steady and on.role == "ground" and on.side is None and on.orientation is None
    assert not on.directional
    hang = RelationReading.parse("hang")
    assert not hang.rests and not hang.steady
    lean = RelationReading.parse("lean+behind+facing")
    assert (lean.position, lean.leant, lean.orientation, lean.side) == ("lean", "behind", "facing", "behind")
    assert RelationReading.parse("facing") == RelationReading.parse("near+facing")  # an orientation alone: near it
    for name in ("levitate", "on+levitate", "on+in", "front+facing+aligned"):
        with pytest.raises(ValueError):
            RelationReading.parse(name)


def test_a_reading_comes_from_the_priors_and_back_from_a_report_verdict():
    prior = ScenePrior(0.3, False, 0.15, "rules", "test", reading=RelationReading.parse("wear", "ground"))
    assert {k: prior.to_dict()[k] for k in ("relation", "source_is_figure", "place")} == {
        "relation": "wear", "source_is_figure": False, "place": None}
    pair = prepared(table(), BALL)
    for reading in (RelationReading.parse("on"), RelationReading.parse("on", "ground"),
                    RelationReading.parse("left+facing")):
        verdict = predicates.verdict(pair, poses(pair, [BALL_POSES["on"]]).matrices()[0], reading)
        assert RelationReading.from_verdict(verdict.to_dict()) == reading
    assert RelationReading.from_verdict(None) is None and RelationReading.from_verdict({}) is None


# --- each relation's own proposals ----------------------------------------------------------------------------------

def _base(pair) -> contact.Proposals:
    """What a builder extends: the search's orientations and contact samples, one proposal at the files' scale."""
    rotations = proposals.orientations(pair, CONFIG, torch.Generator().manual_seed(0))
    one = Poses(torch.zeros(1, 3), torch.tensor([[1.0, 0.0, 0.0, 0.0]]), torch.zeros(1))
    return contact.Proposals(one, ["top"], None, rotations, contact.contact_index(pair, seed=0))


def _built(pair, name: str, seed: int = 0) -> tuple[contact.Proposals, torch.Tensor]:
    reading = RelationReading.parse(name)
    made = SPECS[reading.position].builder(pair, _base(pair), seed, reading, 0.0, SHARE)
    assert made is not None and len(made.poses), name
    with torch.inference_mode():
        held = predicates.holds(predicates.relation_score(pair, made.poses, reading))
    return made, held


def test_lean_proposals_lean_a_stick_against_a_box():
    pair = prepared(box([1, 1, 1], [0, 0.5, 0]), trimesh.creation.cylinder(radius=0.03, height=1.4))
    made, held = _built(pair, "lean")
    assert set(made.region) == {"lean"} and SHARE // 2 <= len(made.poses) <= SHARE
    assert held.float().mean() >= 0.75, held


def test_in_proposals_stand_a_candle_in_a_cup():
    pair = prepared(cup(), trimesh.creation.cylinder(radius=0.05, height=0.3))
    made, held = _built(pair, "in")
    assert set(made.region) == {"contained"} and len(made.poses) <= SHARE  # those left wedged are dropped
    assert held.float().mean() >= 0.75, held


def test_hang_proposals_thread_a_ring_on_a_peg():
    pair = prepared(wall_with_peg(), ring())
    made, held = _built(pair, "hang")
    assert set(made.region) == {"hang"} and SHARE // 2 <= len(made.poses) <= SHARE
    assert held.float().mean() >= 0.5, held


def test_penetrate_proposals_drive_a_stick_into_a_block_all_of_the_share():
    pair = prepared(box([0.3, 0.3, 0.3], [0, 0.15, 0]), trimesh.creation.cylinder(radius=0.015, height=0.8))
    made, held = _built(pair, "penetrate")
    assert made.region == ["pierce"] * SHARE  # not settled: none dropped
    assert held.float().mean() >= 0.75, held


@pytest.mark.parametrize("name", ["front", "left", "behind", "near", "far", "above", "front+facing"])
def test_apart_proposals_stand_where_a_reading_without_contact_says(name):
    pair = prepared(box([1, 1, 1], [0, 0.5, 0]), box([0.3, 0.3, 0.3], [0, 0, 0]))
    pair.target_front, pair.front_trusted = np.array([0.0, 0.0, 1.0]), True
    made, held = _built(pair, name)
    assert set(made.region) == {RelationReading.parse(name).position} and SHARE // 2 <= len(made.poses) <= SHARE
    assert held.float().mean() >= 0.75, (name, held)


def test_extend_builds_the_relations_poses_at_every_scale_of_the_ladder():
    """Scale mode with a guide: the regions' proposals take the ladder's rungs in turn, and so do the relation's own,
    one build per rung sharing the relation's count (before, the middle rung alone)."""
    pair = prepared(box([1, 1, 1], [0, 0.5, 0]), box([0.3, 0.3, 0.3], [0, 0, 0]))
    rungs = [0.0, -0.5, 0.5]
    base = proposals.propose(pair, CONFIG, proposals.region_weights(None), rungs, torch.Generator().manual_seed(0))
    extended = builders.extend(pair, CONFIG, base, RelationReading.parse("near"), 0)
    own = torch.tensor([r == "near" for r in extended.region])
    assert len(extended.poses) == len(base.poses)
    assert sorted(set(extended.poses.log_s[own].tolist())) == sorted(rungs)
    assert int(own.sum()) <= builders.own_count(CONFIG)  # the share split, not multiplied


def test_extend_replaces_as_many_region_proposals_only_for_a_placed_figure():
    pair = prepared(box([1, 1, 1], [0, 0.5, 0]), box([0.3, 0.3, 0.3], [0, 0, 0]))
    base = proposals.propose(pair, CONFIG, proposals.region_weights(None), 0.0, torch.Generator().manual_seed(0))
    extended = builders.extend(pair, CONFIG, base, RelationReading.parse("near"), 0)
    assert len(extended.poses) == len(base.poses) and "near" in extended.region
    for reading in (None, RelationReading.parse("near", "ground"), RelationReading.parse("attach")):
        assert builders.extend(pair, CONFIG, base, reading, 0) is base  # no builder, or not a placed figure
    on = builders.extend(pair, CONFIG, base, RelationReading.parse("on"), 0)  # on the middle of the usual surface
    assert len(on.poses) == len(base.poses) and "on" in on.region
    off = CONFIG.model_copy(update={"relation": False})
    assert builders.extend(pair, off, base, RelationReading.parse("near"), 0) is base


def test_a_pairs_fixed_geometry_is_built_once_while_the_pair_lives():
    """``pairs.per_pair``: what several stages read from one pair (its features, hook points, peg thickness) is
    built on first use and kept for that pair, not for another."""
    from ctp_core.pairs import per_pair

    calls = []

    @per_pair
    def build(pair):
        calls.append(pair)
        return object()

    pair = prepared(box([1, 1, 1], [0, 0.5, 0]), box([0.3, 0.3, 0.3], [0, 0, 0]))
    assert build(pair) is build(pair) and len(calls) == 1
    assert attached.hook_points(pair) is attached.hook_points(pair)
    other = prepared(box([1, 1, 1], [0, 0.5, 0]), box([0.2, 0.2, 0.2], [0, 0, 0]))
    build(other)
    assert len(calls) == 2
