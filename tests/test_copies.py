"""Several of a kind (issue 41): generated scenes whose answer is checkable, the CLI's options, the count's limit
and the prompt's numbers. Geometry only (no guide), ``test`` preset: seconds a scene."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from ctp_core import metrics
from ctp_core.assembly.copies import place_copies
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.io import examples
from ctp_core.priors import get_provider
from ctp_core.reading import counts
from ctp_core.reading.counts import MAX_COPIES, choose

CONFIG = AlignConfig.from_preset("test", model="random:tiny", seed=0, loss={"lambda_clip": 0.0})


def _box(extents) -> trimesh.Trimesh:
    return trimesh.creation.box(extents)


def _posed(mesh: trimesh.Trimesh, matrix) -> trimesh.Trimesh:
    return mesh.copy().apply_transform(np.asarray(matrix))


def _apart(out) -> None:
    """No two copies intersect (exact booleans on these closed meshes)."""
    posed = [_posed(out.source, c.source_to_target) for c in out.copies]
    for i in range(len(posed)):
        for j in range(i + 1, len(posed)):
            assert metrics.intersection_over_union(posed[i], posed[j]).iou <= metrics.PLACEMENT_IOU, (i, j)
    assert out.metrics["none_intersect"] is True


def test_spheres_in_a_bowl_are_all_inside_and_apart():
    bowl, ball = examples._bowl(), trimesh.creation.icosphere(subdivisions=2, radius=0.025)
    # the default preset (no guide): the test preset's 400 samples and 6 steps can leave a ball where one stands
    config = AlignConfig.from_preset("default", seed=0, loss={"lambda_clip": 0.0})
    out = place_copies(bowl, ball, "three balls in the bowl", config, target_name="bowl", source_name="ball")
    assert (out.count, out.arrangement, out.reading.name) == (3, "scatter", "in")
    assert all(c.how == "search" and c.relation["holds"] for c in out.copies)
    lo, hi = bowl.bounds
    for c in out.copies:  # each centre within the bowl's footprint and below its rim
        centre = c.source_to_target[:3, 3]
        assert np.hypot(centre[0] - (lo[0] + hi[0]) / 2, centre[2] - (lo[2] + hi[2]) / 2) < (hi[0] - lo[0]) / 2
        assert centre[1] < hi[1]
    _apart(out)
    assert out.metrics["all_hold"] is True and len(out.timings["per_copy_s"]) == 3


def test_four_boxes_around_a_table_stand_at_its_four_sides_facing_it():
    table, chair = _box((1.2, 0.75, 0.8)), _box((0.3, 0.5, 0.3))
    out = place_copies(table, chair, "four chairs around the table", CONFIG, target_name="table", source_name="chair")
    assert (out.count, out.arrangement, out.reading.name) == (4, "around", "beside+facing")
    sides = set()
    for c in out.copies:
        centre = c.source_to_target[:3, 3]
        assert abs(centre[1] - (-0.375 + 0.25)) < 1e-6  # on the floor the table stands on
        axis = int(np.argmax(np.abs(centre[[0, 2]])))
        sides.add((axis, bool(centre[[0, 2]][axis] > 0)))
        assert np.abs(centre[[0, 2]][axis]) > [0.6, 0.4][axis] + 0.15  # outside the table's side
        front = c.source_to_target[:3, :3] @ [0.0, 0.0, 1.0]  # the box's front (+Z, its file's) turned to the table
        inward = -centre * [1.0, 0.0, 1.0]
        assert front @ inward / np.linalg.norm(inward) > math.cos(math.radians(10))
        assert c.relation["holds"] and [p["name"] for p in c.relation["each"]] == ["beside", "facing"]
    assert len(sides) == 4
    _apart(out)


def test_five_books_stand_in_a_row_on_a_shelf():
    shelf, book = _box((1.0, 0.05, 0.3)), _box((0.04, 0.25, 0.18))
    out = place_copies(shelf, book, "five books in a row on the shelf", CONFIG, target_name="shelf",
                       source_name="book")
    assert (out.count, out.arrangement, out.reading.name) == (5, "row", "on")
    centres = np.array([c.source_to_target[:3, 3] for c in out.copies])
    assert np.allclose(centres[:, 2], 0.0, atol=1e-6)  # along the shelf's long side (x)
    steps = np.diff(centres[:, 0])
    assert np.all(steps > 0.04) and np.ptp(steps) < 1e-6  # side by side, evenly, not touching
    assert np.all(np.abs(centres[:, 1] - (0.025 + 0.125)) < 0.01)  # standing on the top
    assert all(c.relation["holds"] for c in out.copies)
    _apart(out)


def test_a_stack_of_discs_rests_each_on_the_one_below():
    disc = trimesh.creation.cylinder(radius=0.12, height=0.02, sections=32)
    disc.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))  # lying flat (+Y up)
    out = place_copies(_box((1.0, 0.75, 1.0)), disc, "a stack of discs on the table", CONFIG, count=4,
                       target_name="table", source_name="disc")
    assert (out.count, out.arrangement) == (4, "stack")
    heights = np.array([c.source_to_target[1, 3] for c in out.copies])
    assert abs(heights[0] - 0.385) < 0.005 and np.allclose(np.diff(heights), 0.02, atol=0.003)
    assert [c.on for c in out.copies] == ["table", "disc_1", "disc_2", "disc_3"]
    assert all(c.relation["name"] == "on" and c.relation["holds"] for c in out.copies)
    _apart(out)


def test_the_count_is_bounded_with_a_coded_error():
    for bad in (0, MAX_COPIES + 1, 2.5):
        with pytest.raises(ConfigError) as err:
            choose("apples in the bowl", bad)
        assert err.value.code == "count_out_of_range" and err.value.field == "count"
    with pytest.raises(ConfigError) as err:
        choose("twenty apples in the bowl", None, source_name="apple")  # the prompt's number is bounded too
    assert err.value.code == "count_out_of_range"
    with pytest.raises(ConfigError) as err:
        choose("apples", 2, "circle")
    assert err.value.code == "invalid_arrangement"


@pytest.mark.parametrize(("prompt", "source", "count", "arrangement", "relation"), [
    ("three apples in the bowl", "apple", 3, None, "in"),
    ("a pair of vases on the shelf", "vase", 2, None, "on"),
    ("four chairs around the table", "chair", 4, "around", "beside+facing"),
    ("5 books in a row on the shelf", "book", 5, "row", "on"),
    ("a dozen eggs in the basket", "egg", 12, None, "in"),
    ("half a dozen cups on the table", "cup", 6, None, "on"),
    ("a stack of plates on the table", "plate", None, "stack", "on"),
    ("books lined up on the desk", "book", None, "row", "on"),
    ("a man holding two swords", "man", None, None, "hold"),  # the number counts the swords, not the source
    ("a 2 m pole beside the house", "pole", None, None, "beside"),  # a size, not a count
    ("a scarf wrapped around the neck", "scarf", None, None, None),  # "around" here wraps
    ("a pair of glasses on the statue's head", "glasses", None, None, "wear"),  # one object called a pair
    ("a pair of shoes by the door", "shoe", 2, None, None),
])
def test_the_prompt_s_number_and_arrangement_are_read(prompt, source, count, arrangement, relation):
    reading = counts.read_count(prompt, source)
    assert (reading.count, reading.arrangement) == (count, arrangement), reading.why
    one = counts.one_copy(prompt, arrangement or "scatter")
    if relation is not None:  # what each copy is judged by
        assert get_provider("rules").estimate("target", source, one).reading.name == relation, one


def test_the_count_option_wins_and_an_arrangement_alone_means_several():
    assert choose("three apples in the bowl", 2, source_name="apple")[:2] == (2, "scatter")
    assert choose("a stack of plates", None, source_name="plate")[:2] == (3, "stack")
    assert choose("a row of books on the shelf", None, source_name="book")[:2] == (3, "row")
    assert choose("a necklace around her neck", None, source_name="necklace")[:2] == (1, "around")  # one necklace
    assert choose("a book stacked on the box", None, source_name="book")[:2] == (1, "stack")
    assert choose("a cup on the table", None, source_name="cup")[:2] == (1, "scatter")
    assert choose("four chairs around the table", None, "row", "chair")[:2] == (4, "row")


def test_cli_count_and_arrangement_write_one_node_per_copy(tmp_path, capsys):
    from ctp.cli import main

    _box((1.2, 0.75, 0.8)).export(tmp_path / "table.glb")
    _box((0.3, 0.5, 0.3)).export(tmp_path / "chair.glb")
    out, report = tmp_path / "scene.glb", tmp_path / "report.json"
    code = main(["align", str(tmp_path / "table.glb"), str(tmp_path / "chair.glb"), "--prompt", "chairs by the table",
                 "--count", "3", "--arrangement", "around", "--preset", "test", "--no-guidance", "--out", str(out),
                 "--report", str(report), "--quiet"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["count"] == 3 and summary["arrangement"] == "around"
    scene = trimesh.load(out, force="scene")
    assert {"chair_1", "chair_2", "chair_3"} <= set(scene.graph.nodes_geometry)
    written = json.loads(report.read_text())
    assert [c["name"] for c in written["copies"]] == ["chair_1", "chair_2", "chair_3"]
    for c in written["copies"]:
        assert c["transform"]["from_frame"] == "source_file" and c["transform"]["to_frame"] == "target_file"
        matrix, _ = scene.graph[c["name"]]
        assert np.allclose(matrix, c["transform"]["matrix"], atol=1e-6)
        assert c["relation"]["holds"] is True
    assert written["metrics"]["all_hold"] is True and written["metrics"]["none_intersect"] is True


def test_cli_refuses_a_count_over_the_limit_with_exit_2(tmp_path, capsys):
    from ctp.cli import main

    _box((1, 1, 1)).export(tmp_path / "t.glb")
    _box((0.1, 0.1, 0.1)).export(tmp_path / "s.glb")
    code = main(["align", str(tmp_path / "t.glb"), str(tmp_path / "s.glb"), "--prompt", "boxes on the box",
                 "--count", str(MAX_COPIES + 1), "--preset", "test", "--quiet"])
    assert code == 2 and "count_out_of_range" in capsys.readouterr().err


def test_ctp_priors_shows_what_each_copy_is_read_as(capsys):
    from ctp.cli import main

    assert main(["priors", "--target", "shelf", "--source", "book", "--prompt", "5 books in a row on the shelf"]) == 0
    copies = json.loads(capsys.readouterr().out)["copies"]
    assert (copies["count"], copies["arrangement"], copies["copy_relation"]) == (5, "row", "on")
    assert copies["copy_prompt"] == "books on the shelf"
    assert main(["priors", "--target", "table", "--source", "cup", "--prompt", "a cup on the table"]) == 0
    assert "copies" not in json.loads(capsys.readouterr().out)  # one cup: nothing more said
