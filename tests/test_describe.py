"""A description read into a plan (``ctp_core.assembly.describe``): the objects matched to the uploads, each clause a
step read by the pair reader, references back resolved, copies, two grounds, the order, and the errors."""

from __future__ import annotations

import pytest

from ctp_core.assembly.describe import DescriptionError, read_description
from ctp_core.assembly.plan import check_plan, plan_step
from ctp_core.reading import passes

PIANO = ["piano", "stool", "metronome"]
BENCH = ["workbench", "toolbox", "stool", "paint tin"]


def steps(description: str, names: list[str]) -> list[tuple[str, str, tuple[str, ...]]]:
    """(node, relation, on) of each step of the plan, in placing order."""
    return [(s.name, s.relation, s.on) for s in read_description(description, names).steps]


@pytest.mark.parametrize("description", [
    "a piano with its stool in front of it and a metronome on top",  # "its", "it", ellipsis
    "put the stool in front of the piano; stand the metronome on it",  # imperatives, "it" across ";"
    "stool, front of, piano; metronome, on, piano",  # constraint triples
    "The piano. The stool in front of the piano. A metronome on the piano.",  # sentences, "the piano" again
    "a metronome on the piano, and the stool in front of the piano",  # figures before their ground is named
])
def test_one_scene_in_every_style(description):
    plan = read_description(description, PIANO)
    assert plan.base == "piano" and plan.base_upload == 0 and not plan.warnings
    assert sorted((s.name, s.relation, s.on) for s in plan.steps) == [
        ("metronome", "on", ("piano",)), ("stool", "front", ("piano",))]


def test_pronouns_and_a_count_make_copies():
    assert steps("a workbench, a toolbox on it, a stool to its left and two paint tins under it", BENCH) == [
        ("toolbox", "on", ("workbench",)), ("stool", "left", ("workbench",)),
        ("paint tin_1", "under", ("workbench",)), ("paint tin_2", "under", ("workbench",))]


def test_each_puts_one_copy_on_each_copy_of_the_ground():
    assert steps("a cushion on each chair; two chairs beside the table", ["table", "chair", "cushion"]) == [
        ("chair_1", "beside", ("table",)), ("chair_2", "beside", ("table",)),
        ("cushion_1", "on", ("chair_1",)), ("cushion_2", "on", ("chair_2",))]
    plan = read_description("two tables with a lamp on each", ["table", "lamp"])
    assert plan.base == "table_1"  # a copy of the first ground stays put, the other goes beside it
    assert [(s.name, s.on, s.floor) for s in plan.steps] == [
        ("table_2", ("table_1",), True), ("lamp_1", ("table_1",), False), ("lamp_2", ("table_2",), False)]


def test_between_has_two_grounds_and_them_refers_to_the_copies():
    plan = read_description("a lamp between the sofa and the armchair", ["sofa", "armchair", "lamp"])
    assert [(s.name, s.relation, s.on) for s in plan.steps] == [
        ("armchair", "beside", ("sofa",)), ("lamp", "between", ("sofa", "armchair"))]
    assert plan.warnings == ["the armchair is not placed by the description: on the floor beside the sofa"]
    assert steps("lamp, between, sofa, armchair", ["sofa", "armchair", "lamp"])[1] == (
        "lamp", "between", ("sofa", "armchair"))
    assert steps("two paint tins beside the workbench and a brush between them", ["workbench", "paint tin", "brush"]
                 )[-1] == ("brush", "between", ("paint tin_1", "paint tin_2"))


def test_a_sofa_and_an_armchair_then_between_them():
    assert steps("an armchair beside the sofa, a lamp between them", ["sofa", "armchair", "lamp"]) == [
        ("armchair", "beside", ("sofa",)), ("lamp", "between", ("armchair", "sofa"))]  # in the order named


def test_orientation_after_a_comma_stays_with_its_clause():
    plan = read_description("a chair in front of the desk, facing it, and a lamp on the desk",
                            ["desk", "chair", "lamp"])
    assert [(s.name, s.relation) for s in plan.steps] == [("chair", "front+facing"), ("lamp", "on")]
    assert plan.steps[0].prompt == "a chair in front of the desk, facing the desk"


def test_every_ground_is_placed_before_its_figures():
    plan = read_description("a cup on the table, the table on the rug, a rug on the floor", ["cup", "table", "rug"])
    assert plan.base == "rug" and [s.name for s in plan.steps] == ["table", "cup"]
    placed = {plan.base}
    for step in plan.steps:
        assert set(step.on) <= placed
        placed.add(step.name)


def test_the_plan_is_one_assemble_takes():
    """The plan is an assembly plan: its steps pass ``plan_step`` and ``check_plan``, and each step's prompt reads
    as the step's relation with its node as the figure (what ``align`` will read)."""
    plan = read_description("a workbench, a toolbox on it, a stool to its left and two paint tins under it", BENCH)
    files = [f"{n.replace(' ', '_')}.glb" for n in BENCH]
    written = plan.assembly_plan(files)
    assert written["base"] == "workbench.glb" and written["name"] == "workbench"
    checked = [plan_step(entry, f"steps.{i}", assembly_options="") for i, entry in enumerate(written["steps"])]
    check_plan(written["name"], [(s.name, s.on, True) for s in checked])
    for step in plan.steps:
        reading = passes.read_prompt(step.on[0], step.name, step.prompt)
        assert reading.figure and reading.reading.name == step.relation


def test_upload_never_named_goes_beside_the_first_and_is_said():
    plan = read_description("a desk with a monitor on it", ["desk", "monitor", "plant"])
    assert [(s.name, s.relation, s.on, s.floor) for s in plan.steps] == [
        ("plant", "beside", ("desk",), True), ("monitor", "on", ("desk",), False)]
    assert plan.warnings == ["the plant is not named in the description: on the floor beside the desk"]


def test_names_not_said_match_the_uploads_in_order_of_mention():
    plan = read_description("a piano with its stool in front of it", ["obj1", "obj2"])
    assert [(s.name, s.upload, s.on) for s in plan.steps] == [("stool", 1, ("piano",))]
    assert "obj1 as piano, obj2 as stool" in plan.warnings[0]


@pytest.mark.parametrize(("description", "names", "code", "says"), [
    ("a piano with a metronome on top", ["piano", "stool"], "unknown_object", "'metronome'"),
    ("put the stool in front of the organ", ["piano", "stool"], "unknown_object", "'organ'"),
    ("a vase on the table; the table on the vase", ["table", "vase"], "placement_cycle", "circle"),
    ("a stool near the piano; the stool behind the piano", ["piano", "stool"], "placed_twice", "placed twice"),
    ("a piano and a stool", ["piano", "stool"], "nothing_placed", "no object"),
    ("", ["piano", "stool"], "empty_description", "empty"),
    ("a stool in front of the piano", ["piano"], "too_few_objects", "two objects"),
    ("a chair beside the chair", ["chair", "table"], "unclear_clause", "itself"),
    ("a stool in front of the piano", ["piano", "stool", "Piano"], "invalid_description", "two objects"),
])
def test_errors_name_what_is_wrong(description, names, code, says):
    with pytest.raises(DescriptionError) as caught:
        read_description(description, names)
    assert caught.value.code == code and says in caught.value.message


def test_between_them_ends_its_clause_and_a_named_object_is_never_dropped():
    assert steps("a sofa with an armchair to its left, a lamp between them and a coffee table in front of the sofa",
                 ["sofa", "armchair", "lamp", "coffee table"]) == [
        ("armchair", "left", ("sofa",)), ("lamp", "between", ("armchair", "sofa")),
        ("coffee table", "front", ("sofa",))]
    plan = read_description("a lamp on the table, and a table with two chairs", ["table", "chair", "lamp"])
    assert [(s.name, s.floor) for s in plan.steps] == [("chair_1", True), ("chair_2", True), ("lamp", False)]
    assert plan.warnings == ["the chair is not placed by the description: on the floor beside the table"]


def test_a_clause_naming_three_objects_places_all_three():
    """"a lamp on the desk beside the monitor": the monitor, smaller than the desk and placed by nothing else, stands
    on the desk; the lamp beside it, there."""
    plan = read_description("a lamp on the desk beside the monitor", ["desk", "lamp", "monitor"])
    assert [(s.name, s.relation, s.on, s.prompt, s.support) for s in plan.steps] == [
        ("monitor", "on", ("desk",), "the monitor on the desk", "desk"),
        ("lamp", "beside", ("monitor",), "a lamp beside the monitor, on the desk", "desk")]
    assert plan.warnings == []
