"""A scene's steps beyond their own relation: relations said besides (``also``) judged with the step and on the
final scene, a figure turned as the description turns it ("facing the monitor") or squared to what it rests on,
room left for an object said to go between two others, a side relation that stands clear of its ground, and sinks
into open pieces of a mesh measured.

Generated furniture in glTF frames (+Y up, metres, front +Z), geometry only (the test preset).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from ctp_core.assembly import sinking
from ctp_core.assembly.assemble import Step, assemble
from ctp_core.assembly.plan import Also, PlanError, plan_step
from ctp_core.pairs import prepare_pair
from ctp_core.reading.relation import RelationReading
from ctp_core.relations import predicates
from tests.test_scene_placement import box, chair, config, desk, gltf, placed, table


def front_of(assembly, name: str) -> np.ndarray:
    """The object's own front (its file's +Z) as placed, horizontal and unit."""
    entry = next(p for p in assembly.objects if p.name == name)
    front = np.asarray(entry.to_scene.matrix)[:3, :3] @ np.array([0.0, 0.0, 1.0])
    front[1] = 0.0
    return front / np.linalg.norm(front)


def monitor() -> trimesh.Trimesh:
    """A screen 0.5 wide on a foot, its face toward +Z."""
    return gltf(trimesh.util.concatenate([box([0.5, 0.32, 0.04], [0, 0.3, 0]), box([0.2, 0.14, 0.16], [0, 0.07, 0])]))


# --- the plan's also -------------------------------------------------------------------------------------------


def test_a_plan_step_reads_its_also_and_refuses_a_malformed_one():
    step = plan_step({"file": "lamp.glb", "prompt": "a lamp on the desk", "on": "desk",
                      "also": [{"prompt": "the lamp to the right of the monitor", "on": "monitor"}]}, "steps.0",
                     assembly_options="flags")
    assert step.also == (Also("the lamp to the right of the monitor", ("monitor",)),)
    for bad, field in [("right of it", "steps.0.also"), ([{"on": "monitor"}], "steps.0.also.0"),
                       ([{"prompt": "x", "on": "monitor", "why": 1}], "steps.0.also.0.why"),
                       ([{"prompt": "the lamp right of the monitor"}], "steps.0.also.0.on")]:
        with pytest.raises(PlanError) as caught:
            plan_step({"file": "lamp.glb", "prompt": "a lamp on the desk", "also": bad}, "steps.0",
                      assembly_options="flags")
        assert caught.value.field == field


def test_an_also_naming_no_object_of_the_assembly_is_refused():
    from ctp_core.errors import ConfigError

    steps = [Step(monitor(), "monitor", "a monitor on the desk", on="desk",
                  also=(Also("the monitor beside the lamp", ("lamp",)),))]
    with pytest.raises(ConfigError) as caught:
        assemble(desk(), steps, config(), base_name="desk")
    assert caught.value.field == "steps.0.also.0.on"


# --- turned as the description says ----------------------------------------------------------------------------


def test_a_chair_in_front_of_a_desk_facing_a_monitor_at_its_end_faces_the_monitor():
    """The monitor stands at the desk's left end: facing it is not facing the desk's middle."""
    steps = [Step(monitor(), "monitor", "a monitor on the left end of the desk", on="desk"),
             Step(chair(), "chair", "a chair in front of the desk", on="desk",
                  also=(Also("the chair facing the monitor", ("monitor",)),))]
    done = assemble(desk(), steps, config(), base_name="desk")
    centre = placed(done, "chair").bounds.mean(0)
    toward = placed(done, "monitor").bounds.mean(0) - centre
    toward[1] = 0.0
    assert front_of(done, "chair") @ (toward / np.linalg.norm(toward)) > math.cos(math.radians(10))
    said = [r for r in done.whole["relations"] if r["also"]]
    assert [(r["name"], r["relation"], r["on"], r["holds"]) for r in said] == [("chair", "facing", ["monitor"], True)]


def test_a_chair_to_the_left_of_a_table_facing_it_faces_its_centre():
    """Its own relation's "facing" is made exact: the search leaves it within 45 degrees."""
    done = assemble(table(), [Step(chair(), "chair", "a chair to the left of the table, facing it", on="table")],
                    config(), base_name="table")
    centre = placed(done, "chair").bounds.mean(0)
    toward = placed(done, "table").bounds.mean(0) - centre
    toward[1] = 0.0
    assert front_of(done, "chair") @ (toward / np.linalg.norm(toward)) > math.cos(math.radians(5))
    (verdict,) = done.whole["relations"]
    assert verdict["relation"] == "left+facing" and verdict["holds"]


def test_a_monitor_on_a_desk_faces_as_the_desk_faces():
    """Nothing says which way it faces: it is squared to the desk, its screen to the desk's front."""
    done = assemble(desk(), [Step(monitor(), "monitor", "a monitor on the desk", on="desk")], config(),
                    base_name="desk")
    assert front_of(done, "monitor") @ np.array([0.0, 0.0, 1.0]) > math.cos(math.radians(2))


def test_an_also_that_fails_is_reported_failing_in_the_whole():
    """A relation said besides that the placement cannot keep (right of an object at the desk's far right end,
    on the desk) is judged and reported as failing, not dropped."""
    steps = [Step(monitor(), "monitor", "a monitor on the right end of the desk", on="desk"),
             Step(gltf(box([0.1, 0.4, 0.1], [0, 0.2, 0])), "lamp", "a lamp on the desk", on="desk",
                  also=(Also("the lamp to the left of the desk", ("desk",)),))]
    done = assemble(desk(), steps, config(), base_name="desk")
    (also,) = [r for r in done.whole["relations"] if r["also"]]
    assert also["relation"] == "left" and also["holds"] is False and done.whole["all_hold"] is False


# --- room for what goes between -----------------------------------------------------------------------------------


def test_an_object_placed_beside_another_leaves_room_for_what_goes_between_them():
    drum = gltf(trimesh.creation.cylinder(radius=0.3, height=0.9, sections=24,
                                          transform=trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0))))
    drum.apply_translation((0.0, 0.45, 0.0))
    cabinet = gltf(box([0.7, 1.9, 0.5], [0, 0.95, 0]))
    steps = [Step(cabinet, "cabinet", "a cabinet to the right of the table", on="table"),
             Step(drum, "drum", "a drum between the cabinet and the table", on=["cabinet", "table"])]
    done = assemble(table(), steps, config(), base_name="table")
    a, b = placed(done, "cabinet").bounds, placed(done, "table").bounds
    gap = np.max(np.maximum(a[0] - b[1], b[0] - a[1])[[0, 2]])
    assert gap >= 0.6
    verdicts = {r["name"]: r for r in done.whole["relations"]}
    assert verdicts["cabinet"]["holds"] and not verdicts["drum"]["intersects"]
    centre = placed(done, "drum").bounds.mean(0)
    assert a[1][0] < centre[0] < b[0][0]  # in the gap (the cabinet at the table's right: -X)


# --- a side stands clear of its ground --------------------------------------------------------------------------


def test_right_of_holds_clear_of_the_ground_not_behind_its_edge():
    """A lamp whose centre is past the monitor's right end but which stands mostly behind it is not to its right."""
    scene = trimesh.Scene()
    scene.add_geometry(monitor(), node_name="monitor", geom_name="monitor")
    lamp = gltf(box([0.3, 0.4, 0.1], [0, 0.2, 0]))
    pair = prepare_pair(scene, lamp, samples=400, seed=0, on="monitor")
    right = RelationReading.parse("right")
    verdicts = []
    for x in (-0.4, -0.27):  # clear of the monitor's right end (-X: its right faces -X), then 12 cm behind its edge
        pose = trimesh.transformations.translation_matrix((x, 0.0, -0.06))
        verdicts.append(predicates.verdict(pair, pair.local_to_normalised(pose), right).holds)
    assert verdicts == [True, False]


# --- sinking into open pieces -----------------------------------------------------------------------------------


def test_a_sink_into_an_open_slab_is_measured():
    """A slab 4 cm thick left open at its back (no closed piece): a block sunk 2 cm into its top is measured."""
    slab = box([1.0, 0.04, 0.5], [0, 0.72, 0])
    open_slab = trimesh.Trimesh(slab.vertices, slab.faces[slab.face_normals[:, 2] > -0.5], process=False)
    assert not open_slab.is_watertight
    block = box([0.2, 0.2, 0.2], [0, 0.1, 0])
    sunk = sinking.sinking("block", block, trimesh.transformations.translation_matrix((0, 0.74 - 0.02, 0)),
                           [("slab", open_slab, np.eye(4))], floor=0.0)
    assert sunk.to_dict()["penetration_mm"] == pytest.approx(20.0, abs=2.0) and sunk.into == "slab"
    above = sinking.sinking("block", block, trimesh.transformations.translation_matrix((0, 0.7405, 0)),
                            [("slab", open_slab, np.eye(4))], floor=0.0)
    assert above.to_dict()["penetration_mm"] == 0.0
    sheet = trimesh.Trimesh(slab.vertices, slab.faces[slab.face_normals[:, 1] > 0.5], process=False)
    assert sinking.sinking("block", block, trimesh.transformations.translation_matrix((0, 0.5, 0)),
                           [("sheet", sheet, np.eye(4))], floor=0.0).to_dict()["penetration_mm"] == 0.0


# --- brought into contact ------------------------------------------------------------------------------------------


def test_an_object_left_over_or_sunk_into_what_it_stands_on_is_brought_to_contact():
    from ctp_core.assembly.assemble import Placed, _to_contact
    from ctp_core.geometry import frames

    scene = [Placed("table", table(), frames.Similarity(np.eye(4), frames.SCENE, frames.SCENE))]
    block = box([0.2, 0.2, 0.2], [0, 0.1, 0]).vertices
    assert _to_contact(block + [0.0, 0.75 + 0.02, 0.0], scene) == pytest.approx(-0.02, abs=1e-6)  # lowered 2 cm
    assert _to_contact(block + [0.0, 0.75 - 0.003, 0.0], scene) == pytest.approx(0.003, abs=1e-6)  # raised 3 mm
    assert _to_contact(block + [0.0, 0.75, 0.0], scene) == 0.0  # touching: left
    assert _to_contact(block + [2.0, 0.03, 0.0], scene) == pytest.approx(-0.03, abs=1e-6)  # beside it: the floor
    assert _to_contact(block + [0.0, 1.5, 0.0], scene) == 0.0  # far over it: not a gap the search left
