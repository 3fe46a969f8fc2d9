"""The rules provider reads the directional vocabulary: every phrase of ``reading_phrases.csv`` (wordings of
SpatialSense, Rel3D, Sr3D, Holodeck and LayoutVLM, the issue's examples and paraphrases) and of
``reading_phrases_vsr.csv`` (one phrase per relation of the Visual Spatial Reasoning dataset that says where an object
goes, its VSR relation in the ``vsr`` column) gets its expected relation, figure and side (``benchmarks/reading.py
[--phrases tests/reading_phrases_vsr.csv]`` prints the same as an accuracy table).

VSR's 66 relations not in the second list say no place to put an object in a scene: motion ("off", "past", "down",
"deep down", "up", "from", "to", "down from", "across"), parts and makeup ("has as a part", "part of", "consists of",
"with"), "perpendicular to", "beyond", "out of", "meeting", "at" said alone."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from ctp_core.priors import get_provider
from ctp_core.reading import records
from ctp_core.reading.relation import RelationReading

ROWS = list(csv.DictReader((Path(__file__).parent / "reading_phrases.csv").open()))
VSR = list(csv.DictReader((Path(__file__).parent / "reading_phrases_vsr.csv").open()))


def test_the_phrase_list_covers_every_new_relation_from_each_vocabulary():
    named = {p for row in ROWS for p in RelationReading.parse(row["relation"]).relations}
    new = {name for name, r in records.RELATIONS.items() if r.kind != "contact"}
    assert new <= named and len(ROWS) >= 80
    origins = {"spatialsense", "rel3d", "sr3d", "holodeck", "layoutvlm", "issue", "paraphrase"}
    assert origins == {r["origin"] for r in ROWS}


def test_the_vsr_list_has_one_phrase_per_placing_relation_of_vsr():
    assert len(VSR) >= 50 and len({row["vsr"] for row in VSR}) == len(VSR) and {r["origin"] for r in VSR} == {"vsr"}


@pytest.mark.parametrize("row", ROWS + VSR, ids=[row["prompt"] for row in ROWS + VSR])
def test_the_reader_reads_the_relation_its_figure_and_its_side(row):
    prior = get_provider("rules").estimate(row["target"], row["source"], row["prompt"])
    reading = prior.reading
    got = (reading.name, "source" if reading.source_is_figure else "target", reading.side or "")
    assert got == (RelationReading.parse(row["relation"]).name, row["figure"], row["side"]), prior.reason


def test_ctp_priors_shows_the_reading_and_its_side(capsys):
    from ctp.cli import main as ctp_main

    argv = ["priors", "--target", "desk", "--source", "chair", "--prompt", "a chair in front of the desk, facing it"]
    assert ctp_main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["relation"] == "front+facing" and out["source_is_figure"] is True
    assert "desk's front side" in out["reason"] and "'facing' -> facing too" in out["reason"]
