"""A scene as people describe it, read by its sentence structure (``ctp_core.reading.scene``) and planned
(``describe.read_description``): sentences written for these tests in the styles people use (none of them the dev
set's), one construction or more each: a participle or "with" modifier on the right object, coordinated figures and
grounds, nested places, groups, references by the clause's subject and agreement, counts and pairs, a part named by
a possessive, ellipsis; the base that supports others whatever the order of mention; each step's support, its other
relations and its warnings."""

from __future__ import annotations

import pytest

from ctp_core.assembly.describe import DescriptionError, read_description
from ctp_core.assembly.plan import check_plan
from ctp_core.reading import scene


def plan_of(description: str, names: list[str]):
    plan = read_description(description, names)
    check_plan(plan.base, [(s.name, s.on, True) for s in plan.steps])  # a plan assemble takes
    return plan


def steps(description: str, names: list[str]) -> dict[str, tuple[str, tuple[str, ...], str]]:
    """node -> (relation, on, support) of each step."""
    return {s.name: (s.relation, s.on, s.support) for s in plan_of(description, names).steps}


def test_a_participle_after_a_comma_modifies_the_clause_before_and_its_is_the_subject_before():
    plan = plan_of("Place the laptop on the dining table and the coffee mug on the table to its left, then push the "
                   "armchair up next to the table, facing the laptop.", ["dining table", "laptop", "coffee mug",
                                                                          "armchair"])
    assert plan.base == "dining table" and not plan.warnings
    got = {s.name: s for s in plan.steps}
    # "its" is the laptop: the table is the clause's own ground, the mug its figure; the laptop stands on the table
    # too, so the mug is placed left of the laptop, on the table's top (its support), and "on" is said as well
    assert (got["coffee mug"].relation, got["coffee mug"].on, got["coffee mug"].support) == (
        "left", ("laptop",), "dining table")
    assert [(a.relation, a.on) for a in got["coffee mug"].also] == [("on", ("dining table",))]
    assert got["coffee mug"].prompt == "the coffee mug to the left of the laptop, on the dining table"
    assert got["armchair"].relation == "beside" and [(a.relation, a.on) for a in got["armchair"].also] == [
        ("near+facing", ("laptop",))]
    assert [s.name for s in plan.steps].index("laptop") < [s.name for s in plan.steps].index("armchair")


def test_with_attaches_to_the_subject_and_it_is_the_subject_not_the_nearest_noun():
    assert steps("The bookcase stands against the wall with a plant in front of it and two baskets on its lower "
                 "shelf.", ["bookcase", "plant", "basket"]) == {
        "plant": ("front", ("bookcase",), "floor"), "basket_1": ("on", ("bookcase",), "bookcase"),
        "basket_2": ("on", ("bookcase",), "bookcase")}
    got = steps("The crate rests on top of the pallet with three jars standing in it.", ["pallet", "crate", "jar"])
    assert got["crate"] == ("on", ("pallet",), "pallet")
    assert {got[f"jar_{k}"] for k in (1, 2, 3)} == {("in", ("crate",), "crate")}  # the crate, not the pallet


def test_a_part_named_by_a_possessive_is_its_possessor_its_place_kept_where_one_is_read():
    plan = plan_of("A sofa with a plant to its left and a blanket on its seat, and a rug under the sofa.",
                   ["sofa", "plant", "blanket", "rug"])
    got = {s.name: s for s in plan.steps}
    assert (got["blanket"].relation, got["blanket"].on, got["blanket"].prompt) == ("on", ("sofa",),
                                                                                   "a blanket on the sofa")
    assert got["plant"].on == ("sofa",) and got["plant"].relation == "left" and got["rug"].relation == "under"
    assert any("seat" in w for w in got["blanket"].warnings)  # the part is dropped, said so on its step
    shelf = plan_of("a bookcase with two vases on its top shelf", ["bookcase", "vase"]).steps[0]
    assert shelf.prompt == "a vase on the top shelf of the bookcase" and shelf.on == ("bookcase",)
    assert steps("a lamp on the seat of the bench", ["bench", "lamp"]) == {"lamp": ("on", ("bench",), "bench")}


def test_coordinated_figures_are_each_placed_by_their_clause():
    got = steps("Put the radio and the kettle on the counter, and the stool to the right of it.",
                ["counter", "radio", "kettle", "stool"])
    assert got == {"radio": ("on", ("counter",), "counter"), "kettle": ("on", ("counter",), "counter"),
                   "stool": ("right", ("counter",), "floor")}  # "it": the counter (the figures are two)


def test_a_nested_place_is_two_steps_and_the_furniture_is_the_base():
    plan = plan_of("Set the vase on the plate in the centre of the coffee table, and the basket under the table.",
                   ["coffee table", "plate", "vase", "basket"])
    assert plan.base == "coffee table" and not plan.warnings
    assert [(s.name, s.relation, s.on, s.support) for s in plan.steps] == [
        ("basket", "under", ("coffee table",), "floor"), ("plate", "on", ("coffee table",), "coffee table"),
        ("vase", "on", ("plate",), "plate")]
    plan = plan_of("a cup on the saucer on the tray on the table", ["cup", "saucer", "tray", "table"])
    assert plan.base == "table" and [(s.name, s.on) for s in plan.steps] == [
        ("tray", ("table",)), ("saucer", ("tray",)), ("cup", ("saucer",))]


def test_a_place_after_between_is_where_its_grounds_stand():
    plan = plan_of("The candle goes between the bowl and the vase on the dining table.",
                   ["dining table", "bowl", "vase", "candle"])
    assert plan.base == "dining table" and not plan.warnings
    assert [(s.name, s.relation, s.on, s.support) for s in plan.steps] == [
        ("bowl", "on", ("dining table",), "dining table"), ("vase", "on", ("dining table",), "dining table"),
        ("candle", "between", ("bowl", "vase"), "dining table")]


def test_them_is_the_group_named_last_and_next_to_them_is_all_of_it():
    got = steps("Three crates go beside the shelf and the broom next to them, with the ladder behind the shelf.",
                ["shelf", "crate", "broom", "ladder"])
    assert got["broom"] == ("beside", ("crate_1", "crate_2"), "floor")
    assert got["ladder"] == ("behind", ("shelf",), "floor")
    got = steps("A lamp and a clock stand on the nightstand and a photo frame next to them.",
                ["nightstand", "lamp", "clock", "photo frame"])
    assert got["photo frame"] == ("beside", ("lamp", "clock"), "nightstand")  # on the same top as the group


def test_them_without_a_group_is_the_subject_and_its_ground():
    got = steps("A desk with a printer on it and a chair in front; the bookcase goes to the left of the desk, with "
                "the bin between them.", ["desk", "printer", "chair", "bookcase", "bin"])
    assert got["chair"] == ("front", ("desk",), "floor")  # "in front": of the desk, the ground left out
    assert got["printer"] == ("on", ("desk",), "desk")
    assert got["bin"] == ("between", ("bookcase", "desk"), "floor")


def test_copies_of_a_count_between_them_and_both_and_each():
    got = steps("Two lamps stand beside the sofa with the side table between them.", ["sofa", "lamp", "side table"])
    assert got["side table"] == ("between", ("lamp_1", "lamp_2"), "floor")
    assert steps("two benches with a pot plant on each", ["bench", "pot plant"]) == {
        "bench_2": ("beside", ("bench_1",), "floor"), "pot plant_1": ("on", ("bench_1",), "bench_1"),
        "pot plant_2": ("on", ("bench_2",), "bench_2")}
    got = steps("a crate beside the barrel, and a lantern next to both", ["barrel", "crate", "lantern"])
    assert got["lantern"] == ("beside", ("crate", "barrel"), "floor")


def test_a_pair_of_is_two_copies_unless_one_thing_is_called_a_pair():
    got = steps("A lamp and a clock stand on the nightstand, and a pair of slippers is under the bed; the "
                "nightstand is next to the bed.", ["bed", "nightstand", "lamp", "clock", "slipper"])
    assert got["slipper_1"] == got["slipper_2"] == ("under", ("bed",), "floor")
    assert got["nightstand"] == ("beside", ("bed",), "floor")
    assert steps("a pair of glasses on the desk", ["desk", "glasses"]) == {"glasses": ("on", ("desk",), "desk")}


def test_ellipsis_repeats_the_clause_before_and_a_fronted_place_is_its_figures():
    assert steps("a mug on the desk, and the plate too", ["desk", "mug", "plate"]) == {
        "mug": ("on", ("desk",), "desk"), "plate": ("on", ("desk",), "desk")}
    assert steps("next to the bed, a nightstand with a lamp on it", ["bed", "nightstand", "lamp"]) == {
        "nightstand": ("beside", ("bed",), "floor"), "lamp": ("on", ("nightstand",), "nightstand")}


def test_the_base_supports_others_whatever_the_order_of_mention():
    plan = plan_of("the mug goes on the tray, and the tray on the desk", ["mug", "tray", "desk"])
    assert plan.base == "desk" and [s.name for s in plan.steps] == ["tray", "mug"]
    plan = plan_of("a vase on the shelf, with the armchair next to the lamp", ["lamp", "vase", "shelf", "armchair"])
    assert plan.base == "shelf"  # it holds the vase; the lamp holds nothing
    assert [w for s in plan.steps for w in s.warnings] == [
        "the lamp is not placed by the description: on the floor beside the shelf"]


def test_an_orientation_with_a_room_ground_does_not_hide_the_objects_relation():
    plan = plan_of("a chair with its back to the wall in front of the desk", ["desk", "chair"])
    assert [(s.name, s.relation, s.on) for s in plan.steps] == [("chair", "front", ("desk",))]
    assert "wall" in plan.steps[0].warnings[0]


def test_copies_around_a_table_face_it():
    got = steps("Four chairs stand around the table with the lamp between them.", ["table", "chair", "lamp"])
    assert {got[f"chair_{k}"] for k in range(1, 5)} == {("beside+facing", ("table",), "floor")}


def test_the_plan_and_its_steps_carry_supports_also_and_warnings():
    plan = read_description("Place the laptop on the dining table and the coffee mug on the table to its left, and "
                            "a plant", ["dining table", "laptop", "coffee mug", "plant"])
    written = plan.to_dict()
    assert written["base_support"] == "floor" and written["reader"] == "rules"
    mug = next(s for s in written["steps"] if s["name"] == "coffee mug")
    assert mug["support"] == "dining table" and mug["also"][0]["relation"] == "on"
    plant = next(s for s in written["steps"] if s["name"] == "plant")
    assert plant["floor"] and plant["warnings"] == written["warnings"] == [
        "the plant is not placed by the description: on the floor beside the dining table"]


@pytest.mark.parametrize(("description", "names", "code"), [
    ("a rug under the bed and the bed on it", ["bed", "rug"], "placement_cycle"),
    ("the vase on the shelf with a candle on its rim too", ["shelf", "vase", "lamp"], "unknown_object"),
    ("a candle next to itself", ["candle", "shelf"], "unclear_clause"),
])
def test_what_cannot_be_read_is_still_an_error(description, names, code):
    with pytest.raises(DescriptionError) as caught:
        read_description(description, names)
    assert caught.value.code == code


def test_the_scene_reader_reads_words_only():
    reading = scene.read_scene("the teapot on the tray in the middle of the table", ["table", "tray", "teapot"])
    assert [(s.figure, s.relation, s.grounds, s.derived) for s in reading.said] == [
        ("teapot", "on", ("tray",), False), ("tray", "on", ("table",), True)]


def test_a_verb_of_placing_that_is_also_a_cue_is_the_order_not_the_relation():
    assert steps("Hang the mirror above the sink, and put the soap dish next to it.",
                 ["sink", "mirror", "soap dish"]) == {"mirror": ("above", ("sink",), "floor"),
                                                      "soap dish": ("beside", ("sink",), "floor")}


def test_a_place_in_the_room_is_no_object_and_the_objects_relation_places_the_figure():
    plan = plan_of("Put a plant in the corner next to the bookshelf.", ["bookshelf", "plant"])
    assert [(s.name, s.relation, s.on) for s in plan.steps] == [("plant", "beside", ("bookshelf",))]
    assert "corner" in plan.steps[0].warnings[0]


def test_a_way_to_face_after_a_place_may_be_of_the_same_ground():
    got = steps("a desk with a monitor on it, a chair in front of it, facing it, and a lamp to its right",
                ["desk", "monitor", "chair", "lamp"])
    assert got["chair"] == ("front+facing", ("desk",), "floor") and got["lamp"] == ("right", ("desk",), "floor")


def test_on_a_top_and_beside_what_stands_there_is_placed_beside_it_on_that_top():
    got = {s.name: s for s in plan_of("Put the kettle on the counter and the toaster on the counter next to it.",
                                      ["counter", "kettle", "toaster"]).steps}
    assert (got["toaster"].relation, got["toaster"].on, got["toaster"].support) == ("beside", ("kettle",), "counter")
    # beside something that stands elsewhere: the relation of support places it, the other is said as well
    got = {s.name: s for s in plan_of("the kettle next to the counter and the toaster on the counter next to it",
                                      ["counter", "kettle", "toaster"]).steps}
    assert (got["toaster"].relation, got["toaster"].on) == ("on", ("counter",))
    assert [(a.relation, a.on) for a in got["toaster"].also] == [("beside", ("kettle",))]


def test_a_compound_name_said_by_its_last_part_and_a_place_said_by_a_possessive():
    got = steps("Three paint cans go under the workbench and the ladder next to them, with the stool in front of the "
                "bench.", ["workbench", "paint can", "ladder", "stool"])
    assert got["stool"] == ("front", ("workbench",), "floor")  # "the bench": the workbench
    assert got["ladder"] == ("beside", ("paint can_1", "paint can_2"), "floor")
    plan = plan_of("A picnic table with a cooler to its left and a basket on its top, and a frisbee under the table.",
                   ["picnic table", "cooler", "basket", "frisbee"])
    assert plan.base == "picnic table" and not plan.warnings  # the frisbee is no ground of "on its top"
    assert {s.name: s.prompt for s in plan.steps}["basket"] == "a basket on the top of the picnic table"


def test_on_each_side_is_beside_and_a_support_read_by_the_reader():
    assert steps("A bed with a nightstand on each side and a lamp on each nightstand.", ["bed", "nightstand", "lamp"]
                 ) == {"nightstand": ("beside", ("bed",), "floor"), "lamp": ("on", ("nightstand",), "nightstand")}
    got = steps("A sofa with two cushions on it and a throw blanket over its arm, and the coffee table in front of it.",
                ["sofa", "cushion", "throw blanket", "coffee table"])
    assert got["throw blanket"] == ("lie", ("sofa",), "sofa")  # "over", said of a cloth: draped on it
    assert got["coffee table"] == ("front", ("sofa",), "floor")


def test_a_relation_said_first_places_every_figure_after_it():
    assert steps("On the desk are a laptop and a lamp.", ["desk", "laptop", "lamp"]) == {
        "laptop": ("on", ("desk",), "desk"), "lamp": ("on", ("desk",), "desk")}


def test_a_place_of_the_ground_said_with_the_cue_stays_in_the_prompt():
    plan = plan_of("The mug sits at the edge of the desk.", ["desk", "mug"])
    assert [(s.relation, s.prompt) for s in plan.steps] == [("on", "the mug sits at the edge of the desk")]


def test_it_is_not_a_ground_the_clause_names_elsewhere():
    got = {s.name: s for s in plan_of("Put the teapot on the tray and the cups next to it on the tray too.",
                                      ["tray", "teapot", "cup"]).steps}
    assert (got["cup"].relation, got["cup"].on, got["cup"].support) == ("beside", ("teapot",), "tray")
    assert got["cup"].prompt == "the cup next to the teapot, on the tray"


def test_one_more_of_a_kind_is_said_not_guessed_and_no_sofa_goes_on_an_armchair():
    plan = plan_of("Two cushions on the sofa and one on the armchair.", ["sofa", "cushion", "armchair"])
    assert plan.base == "sofa" and [(s.name, s.on) for s in plan.steps if not s.floor] == [
        ("cushion_1", ("sofa",)), ("cushion_2", ("sofa",))]
    assert any("one on the armchair" in w for w in plan.warnings)


def test_a_list_of_figures_ending_in_and_is_placed_whole_and_a_first_phrase_alone_is_the_topic():
    assert steps("A laptop, a mug and a lamp on the desk, and the chair in front of it.",
                 ["desk", "laptop", "mug", "lamp", "chair"]) == {
        "laptop": ("on", ("desk",), "desk"), "mug": ("on", ("desk",), "desk"), "lamp": ("on", ("desk",), "desk"),
        "chair": ("front", ("desk",), "floor")}
    assert steps("The sofa has a cushion on it, and the lamp is to the left.", ["sofa", "cushion", "lamp"]) == {
        "cushion": ("on", ("sofa",), "sofa"), "lamp": ("left", ("sofa",), "floor")}


def test_a_relation_after_a_ground_says_where_that_ground_stands_where_the_sizes_say_so():
    assert steps("Place the lamp on the nightstand by the bed.", ["bed", "nightstand", "lamp"]) == {
        "nightstand": ("beside", ("bed",), "floor"), "lamp": ("on", ("nightstand",), "nightstand")}
    assert steps("Place a lamp on each of the two nightstands beside the bed.", ["bed", "nightstand", "lamp"]) == {
        "nightstand_1": ("beside", ("bed",), "floor"), "nightstand_2": ("beside", ("bed",), "floor"),
        "lamp_1": ("on", ("nightstand_1",), "nightstand_1"), "lamp_2": ("on", ("nightstand_2",), "nightstand_2")}


def test_it_beside_something_is_rather_a_thing_of_its_size_than_the_furniture_it_stands_on():
    got = steps("Put the laptop on the desk and the phone beside it.", ["desk", "laptop", "phone"])
    assert got["phone"] == ("beside", ("laptop",), "desk")  # on the desk, beside the laptop


def test_them_after_a_clause_of_two_objects_is_those_two_not_the_place_said_first():
    got = steps("On the café table, put the teapot next to the paper bag and the wooden bowl in front of them.",
                ["café table", "teapot", "paper bag", "wooden bowl"])
    assert got["wooden bowl"] == ("front", ("teapot", "paper bag"), "café table")


def test_flanking_and_the_other_side():
    assert steps("Two potted plants flank the bench, one on each side.", ["bench", "potted plant"]) == {
        "potted plant_1": ("beside", ("bench",), "floor"), "potted plant_2": ("beside", ("bench",), "floor")}
    got = steps("Next to the armchair stands a floor lamp, and a side table is on its other side.",
                ["armchair", "floor lamp", "side table"])
    assert got == {"floor lamp": ("beside", ("armchair",), "floor"), "side table": ("beside", ("armchair",), "floor")}


# One sentence in the style of each dev scene, with other objects and words: every object placed by its clause,
# the base, the references (node -> relation, on).
LIKE_THE_DEV_SET = [
    ("Set the TV on the media console and the speaker on the console to its left, then push the armchair "
     "up in front of the console, facing the TV.",
     ["media console", "TV", "speaker", "armchair"], "media console",
     {"TV": ("on", ("media console",)), "speaker": ("left", ("TV",)), "armchair": ("front", ("media console",))}),
    ("Three baskets go under the bench and the umbrella stand next to them, with the coat rack behind the "
     "bench.",
     ["bench", "basket", "umbrella stand", "coat rack"], "bench",
     {"basket_1": ("under", ("bench",)), "basket_2": ("under", ("bench",)), "basket_3": ("under", ("bench",)),
      "umbrella stand": ("beside", ("basket_1", "basket_2")), "coat rack": ("behind", ("bench",))}),
    ("Put two spoons in the jar and the whisk in the pot, then set the pot down next to the jar.",
     ["jar", "spoon", "pot", "whisk"], "jar",
     {"spoon_1": ("in", ("jar",)), "spoon_2": ("in", ("jar",)), "pot": ("beside", ("jar",)),
      "whisk": ("in", ("pot",))}),
    ("The bed faces the wardrobe, with a nightstand to the right of the bed and two pillows on it.",
     ["wardrobe", "bed", "nightstand", "pillow"], "wardrobe",
     {"bed": ("near+facing", ("wardrobe",)), "nightstand": ("right", ("bed",)), "pillow_1": ("on", ("bed",)),
      "pillow_2": ("on", ("bed",))}),
    ("Put the vase on the doily in the middle of the side table, and the basket under the table.",
     ["side table", "doily", "vase", "basket"], "side table",
     {"basket": ("under", ("side table",)), "doily": ("on", ("side table",)), "vase": ("on", ("doily",))}),
    ("The desk sits in front of the window seat and the bookshelf next to the window seat; a globe and a "
     "clock stand on the desk, and a pair of slippers is under the window seat.",
     ["window seat", "desk", "bookshelf", "globe", "clock", "slipper"], "window seat",
     {"desk": ("front", ("window seat",)), "bookshelf": ("beside", ("window seat",)), "globe": ("on", ("desk",)),
      "clock": ("on", ("desk",)), "slipper_1": ("under", ("window seat",)), "slipper_2": ("under", ("window seat",))}),
    ("The candle goes between the salt shaker and the pepper mill on the dining table.",
     ["dining table", "salt shaker", "pepper mill", "candle"], "dining table",
     {"salt shaker": ("on", ("dining table",)), "pepper mill": ("on", ("dining table",)),
      "candle": ("between", ("salt shaker", "pepper mill"))}),
    ("A picnic table with a cooler to its right and a plate on its top, and a ball under the table.",
     ["picnic table", "cooler", "plate", "ball"], "picnic table",
     {"cooler": ("right", ("picnic table",)), "plate": ("on", ("picnic table",)),
      "ball": ("under", ("picnic table",))}),
    ("Put the vase and the clock on the mantelpiece, and the armchair to the right of it.",
     ["mantelpiece", "vase", "clock", "armchair"], "mantelpiece",
     {"vase": ("on", ("mantelpiece",)), "clock": ("on", ("mantelpiece",)), "armchair": ("right", ("mantelpiece",))}),
    ("A counter with a microwave on it and a stool in front; the fridge goes to the left of the counter, "
     "with the trash can between them.",
     ["counter", "microwave", "stool", "fridge", "trash can"], "counter",
     {"microwave": ("on", ("counter",)), "stool": ("front", ("counter",)), "fridge": ("left", ("counter",)),
      "trash can": ("between", ("fridge", "counter"))}),
    ("Two bollards stand next to the bench with the bin between them.",
     ["bench", "bollard", "bin"], "bench",
     {"bollard_1": ("beside", ("bench",)), "bollard_2": ("beside", ("bench",)),
      "bin": ("between", ("bollard_1", "bollard_2"))}),
    ("The basket sits on top of the stool with three apples lying in it.",
     ["stool", "basket", "apple"], "stool",
     {"basket": ("on", ("stool",)), "apple_1": ("in", ("basket",)), "apple_2": ("in", ("basket",)),
      "apple_3": ("in", ("basket",))}),
]


@pytest.mark.parametrize(("description", "names", "base", "expected"), LIKE_THE_DEV_SET,
                         ids=[c[0][:40] for c in LIKE_THE_DEV_SET])
def test_sentences_in_the_dev_sets_styles(description, names, base, expected):
    plan = plan_of(description, names)
    assert plan.base == base and not plan.warnings
    assert {s.name: (s.relation, s.on) for s in plan.steps} == expected
