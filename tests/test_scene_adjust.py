"""One object of a finished scene adjusted by hand (``ctp_core.assembly.adjusted``) and what each object stands on
(``ctp_core.assembly.standing``), on the generated table, plate and cup of ``test_assemble``: the cup moved off the
plate onto the table top and dropped, every relation judged again, the scene and its report saved."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ctp_core.assembly.adjusted import adjust_object
from ctp_core.assembly.assemble import Step, assemble, scene_of
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.export import adjusted_scene_report, assembly_glb, assembly_report
from ctp_core.io import load_objects
from tests.test_assemble import GEOMETRY_ONLY, PLAN, table_plate_cup


@pytest.fixture(scope="module")
def scene():
    meshes = table_plate_cup()
    config = AlignConfig.from_preset("test", model="random:tiny", seed=0, loss={"lambda_clip": 0.0},
                                     optim={"steps": GEOMETRY_ONLY["steps"]})
    assembly = assemble(meshes["table"], [Step(meshes[n], n, p, on=on) for n, p, on in PLAN], config,
                        base_name="table")
    return assembly, assembly_report(assembly), config


def test_the_report_says_what_each_object_stands_on(scene):
    _, report, _ = scene
    assert {o["name"]: o["stands_on"] for o in report["objects"]} == {"table": "floor", "plate": "table",
                                                                     "cup": "plate"}


def test_the_cup_moved_onto_the_table_is_dropped_and_every_relation_judged_again(scene):
    assembly, report, config = scene
    glb = load_objects(assembly_glb(assembly), filename="result.glb")
    cup = next(o for o in report["objects"] if o["name"] == "cup")
    moved = np.array(cup["transform"]["matrix"], dtype=np.float64)
    moved[0, 3] += 0.4  # off the plate (24 cm wide), over the table top (1.2 m), and up in the air
    moved[1, 3] += 0.2
    done = adjust_object(glb, report, "cup", moved, [config, config], settle="drop")
    table_top = 0.75  # the top's height (test_assemble: a 0.1 m slab centred at 0.7)
    lowest = float(done.objects[2].mesh.copy().apply_transform(done.adjusted.source_to_target).bounds[0][1])
    assert done.adjusted.settled and abs(lowest - table_top) < 0.01, lowest
    assert done.stands_on == {"table": "floor", "plate": "table", "cup": "table"}
    verdicts = {r["name"]: r for r in done.whole["relations"]}
    assert verdicts["plate"]["holds"] and not verdicts["cup"]["holds"]  # the cup is no longer on the plate
    assert done.whole["none_intersect"]

    saved = adjusted_scene_report(report, done, at="2026-12-06T12:00:00+00:00")
    assert saved["adjusted"] and saved["adjustment"]["object"] == "cup"
    assert saved["adjustment"]["original_objects"] == report["objects"]
    np.testing.assert_allclose(saved["stages"][1]["transform"]["matrix"], done.adjusted.source_to_target)
    again = load_objects(trimesh.exchange.gltf.export_glb(scene_of(done.objects)), filename="r.glb")
    assert list(again.geometry) == ["table", "plate", "cup"]  # the same nodes, the cup's moved


def test_the_base_and_unknown_objects_are_refused(scene):
    assembly, report, config = scene
    glb = load_objects(assembly_glb(assembly), filename="result.glb")
    for name in ("table", "saucer"):
        with pytest.raises(ConfigError) as refused:
            adjust_object(glb, report, name, np.eye(4), [config, config])
        assert refused.value.code == "invalid_object"
