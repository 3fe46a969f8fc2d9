"""``between``: the first relation with two grounds, through the reading, the judge, the builder and a run."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from test_predicates import box, pose, poses

from ctp_core.align import align
from ctp_core.config import AlignConfig
from ctp_core.pairs import prepare_pair
from ctp_core.reading import cues
from ctp_core.reading.records import RELATIONS
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import predicates

BETWEEN = RelationReading.parse("between")
POST = trimesh.creation.cylinder(radius=0.15, height=0.6, transform=trimesh.transformations.rotation_matrix(
    np.pi / 2, [1, 0, 0]))  # upright (+Y), its centre at its origin: stands at y = 0.3


def scene() -> trimesh.Scene:
    """A 2 m sofa (x from -2.6 to -0.6) and a 0.9 m armchair (x from 0.95 to 1.85), both on y = 0, 1.55 apart."""
    out = trimesh.Scene()
    out.add_geometry(box([2.0, 0.8, 0.9], [-1.6, 0.4, 0.0]), node_name="sofa", geom_name="sofa")
    out.add_geometry(box([0.9, 0.8, 0.9], [1.4, 0.4, 0.0]), node_name="armchair", geom_name="armchair")
    return out


def prepared(on=("sofa", "armchair")):
    return prepare_pair(scene(), POST, samples=1500, seed=0, canonicalise=False, on=list(on) if on else None)


@pytest.mark.parametrize("prompt, grounds", [
    ("a lamp between the sofa and the armchair", ["sofa", "armchair"]),
    ("put the stool in between the piano and the wall.", ["piano", "wall"]),
    ("a rug in the middle of the bed and the desk, facing the window", ["bed", "desk"]),
    ("a table flanked by two chairs", ["chairs"]),
])
def test_the_reader_reads_between_and_its_two_grounds(prompt, grounds):
    cue = cues.find_cue(prompt)
    assert cue.relation.name == "between"
    assert cues.ground_phrases(prompt, cue) == grounds


def test_in_the_middle_of_one_thing_is_not_between():
    assert cues.find_cue("a vase in the middle of the table").relation.name != "between"


def test_named_grounds_match_placed_objects_in_the_prompts_order():
    placed = ["floor", "armchair", "sofa"]
    assert cues.named_grounds("a lamp between the big sofa and the armchair", placed) == ["sofa", "armchair"]
    assert cues.named_grounds("a lamp between the sofa and the piano", placed) == []
    assert cues.named_grounds("a lamp on the sofa", placed) == []


def test_between_has_two_grounds_and_only_it():
    assert RELATIONS["between"].grounds == 2
    assert [name for name, record in RELATIONS.items() if record.grounds != 1] == ["between"]


def test_the_judge_holds_in_the_gap_only():
    pair = prepared()
    assert len(pair.grounds) == 2
    places = {"middle": [0.17, 0.3, 0.0], "near the armchair": [0.7, 0.3, 0.0], "beyond the armchair": [2.2, 0.3, 0.0],
              "touching the sofa": [-0.45, 0.3, 0.0], "lifted": [0.17, 0.9, 0.0], "far behind": [0.17, 0.3, 3.0]}
    score = predicates.relation_score(pair, poses(pair, [pose(p) for p in places.values()]), BETWEEN)
    held = dict(zip(places, predicates.holds(score).tolist(), strict=True))
    assert held == {"middle": True, "near the armchair": True, "beyond the armchair": False,
                    "touching the sofa": False, "lifted": False, "far behind": False}, score
    prefer = predicates.preference(pair, poses(pair, [pose(places["middle"]), pose(places["near the armchair"])]),
                                   BETWEEN)
    assert prefer[0] < prefer[1]


def test_with_one_ground_between_never_holds():
    pair = prepared(on=("sofa",))
    score = predicates.relation_score(pair, poses(pair, [pose([0.17, 0.3, 0.0])]), BETWEEN)
    assert not bool(predicates.holds(score)[0])


def test_a_run_places_the_source_between_the_two_objects_its_prompt_names():
    """The assembly's way: ``on`` names one placed object, the prompt names two; the run relates to both."""
    config = AlignConfig.from_preset("test").merged({"loss": {"lambda_clip": 0.0}})
    source = POST.copy()
    source.apply_translation([5.0, 0.0, 3.0])
    result = align(scene(), source, "a lamp between the sofa and the armchair", config, on="sofa",
                   target_name="sofa", source_name="lamp")
    assert result.grounds == ["sofa", "armchair"] and result.on == "sofa"
    assert result.relation["name"] == "between" and result.relation["holds"], result.relation
    centre = result.source_to_target[:3, :3] @ source.bounds.mean(0) + result.source_to_target[:3, 3]
    assert -0.6 < centre[0] < 0.95 and abs(centre[2]) < 0.45
    assert float(torch.as_tensor(centre[1])) < 0.6  # on the floor
    assert np.isfinite(result.source_to_target).all()
