"""Iterative assembly (``ctp_core.assembly.assemble``, ``ctp assemble``) on a generated three-object scene: a table,
a plate on the table, a cup on the plate. With the guidance term off the geometry alone must leave every
object touching the one it was placed on without interpenetrating any earlier one, measured on the GLB
as written (its nodes loaded back), not on the transforms the run reports."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import trimesh
from scipy.spatial.distance import pdist

from ctp.cli import main
from ctp_core.assembly.assemble import Step, assemble
from ctp_core.assembly.plan import PlanError, PlanStep, plan_step
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.export import assembly_glb, assembly_report
from ctp_core.geometry import frames
from ctp_core.io import load_objects
from ctp_core.pairs import objects, render_arrangement

TOUCH_M = 0.01  # a gap under 1 cm (the scene is 1.2 m wide) is contact for these soft terms
DEPTH_M = 0.005  # deepest point of one object inside another: under a quarter of the plate's thickness
GEOMETRY_ONLY = {"preset": "test", "lambda_clip": 0.0, "steps": 120, "seed": 0}  # API option names
PLAN = [("plate", "a plate on the table", "table"), ("cup", "a cup on the plate", "plate")]


def _coloured(mesh: trimesh.Trimesh, rgb) -> trimesh.Trimesh:
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([*rgb, 255], (len(mesh.vertices), 1)))
    return mesh


def table_plate_cup() -> dict[str, trimesh.Trimesh]:
    """Three closed meshes in their own file frames: a 1.2 m table top, a 24 cm plate, a 9 cm cup."""
    table = _coloured(trimesh.creation.box((1.2, 0.1, 0.8)), (150, 100, 60))
    table.apply_translation((0.0, 0.7, 0.0))
    plate = _coloured(trimesh.creation.cylinder(radius=0.12, height=0.02, sections=32), (240, 240, 240))
    plate.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    cup = _coloured(trimesh.creation.cylinder(radius=0.04, height=0.09, sections=24), (200, 30, 30))
    cup.apply_translation((3.0, -1.0, 2.0))  # the file pose is arbitrary
    return {"table": table, "plate": plate, "cup": cup}


def check_contacts(glb: bytes, plan=PLAN) -> dict[str, trimesh.Trimesh]:
    """Load the GLB's nodes back; every placed object touches its ``on`` and enters no earlier object."""
    placed = dict(objects(load_objects(glb, filename="scene.glb")))
    names = list(placed)
    assert names == ["table", *(name for name, _, _ in plan)]
    for name, _, on in plan:
        points = trimesh.sample.sample_surface(placed[name], 2000, seed=0)[0]
        gap = trimesh.proximity.closest_point(placed[on], points)[1].min()
        assert gap < TOUCH_M, f"{name} is {gap:.4f} m from {on}"
        for earlier in names[:names.index(name)]:
            depth = trimesh.proximity.signed_distance(placed[earlier], points).max()  # > 0 inside
            assert depth < DEPTH_M, f"{name} is {depth:.4f} m inside {earlier}"
    return placed


@pytest.fixture(scope="module")
def meshes():
    return table_plate_cup()


@pytest.fixture(scope="module")
def assembly(meshes):
    config = AlignConfig.from_preset("test", model="random:tiny", seed=0, loss={"lambda_clip": 0.0},
                                     optim={"steps": GEOMETRY_ONLY["steps"]})
    stages = []
    steps = [Step(meshes[name], name, prompt, on=on) for name, prompt, on in PLAN]
    result = assemble(meshes["table"], steps, config, base_name="table",
                      on_step=lambda i, n, step: stages.append((i, n, step.name)))
    assert stages == [(1, 2, "plate"), (2, 2, "cup")]
    return result


def test_three_stages_touch_without_interpenetrating(assembly):
    check_contacts(assembly_glb(assembly))


def test_glb_reproduces_every_object_and_its_materials(assembly, meshes):
    placed = dict(objects(load_objects(assembly_glb(assembly), filename="scene.glb")))
    for name, mesh in meshes.items():
        # rigid placement: the size (largest distance between two vertices) and the area are the file's
        assert abs(pdist(placed[name].vertices).max() - pdist(mesh.vertices).max()) < 1e-5, name
        assert abs(placed[name].area - mesh.area) < 1e-5, name
        colours = placed[name].visual.vertex_colors[:, :3]
        assert (colours == mesh.visual.vertex_colors[0, :3]).all(), name
    np.testing.assert_allclose(placed["table"].vertices, meshes["table"].vertices, atol=1e-6)  # the base stays


def test_placed_objects_never_move(assembly, meshes):
    first, second = assembly.results
    plate_after_stage_1 = frames.Similarity(first.result.source_to_target, frames.SOURCE_FILE, frames.SCENE)
    seen_by_stage_2 = dict(objects(second.result.target))
    np.testing.assert_allclose(seen_by_stage_2["plate"].vertices, plate_after_stage_1.apply(meshes["plate"].vertices),
                               atol=1e-6)
    np.testing.assert_allclose(seen_by_stage_2["table"].vertices, meshes["table"].vertices, atol=1e-9)
    assert assembly.objects[1].to_scene.matrix.tolist() == plate_after_stage_1.matrix.tolist()


def test_the_preview_is_the_final_scene_and_steps_render_none(assembly):
    """The steps render no preview or thumbnails of their own; the assembly's preview is four views of the final
    scene, every object where it was kept (the last one on the others), in colour."""
    assert all(s.result.preview is None and s.result.thumbnails is None for s in assembly.results)
    preview = assembly.preview
    assert preview.shape == (4, 224, 224, 3) and preview.dtype == np.uint8
    last, others = assembly.objects[-1], assembly.scene()
    others.delete_geometry(last.name)
    views = render_arrangement(others, last.mesh, np.asarray(last.to_scene.matrix), views=4)
    np.testing.assert_allclose(preview / 255.0, views.permute(0, 2, 3, 1).numpy(), atol=1 / 255)
    assert (preview.std(axis=-1) > 20).any(axis=(1, 2)).all()  # coloured objects in every view, not a blank one


def test_report_lists_every_stage(assembly):
    report = json.loads(json.dumps(assembly_report(assembly)))
    assert report["frame"] == "scene" and [o["name"] for o in report["objects"]] == ["table", "plate", "cup"]
    for stage, (name, prompt, on) in zip(report["stages"], PLAN, strict=True):
        assert (stage["name"], stage["prompt"], stage["on"]) == (name, prompt, on)
        assert (stage["transform"]["from_frame"], stage["transform"]["to_frame"]) == ("source_file", "scene")
        matrix = np.array(stage["transform"]["matrix"])
        assert matrix.shape == (4, 4) and len(stage["transform"]["rotation_wxyz"]) == 4
        assert on in stage["hparams"]["reason"] and name in stage["hparams"]["reason"]  # priors got both names
        assert stage["timings"]["total_s"] > 0
    assert report["objects"][0]["transform"]["matrix"] == np.eye(4).tolist()


def test_plan_errors_name_the_step(meshes):
    config = AlignConfig.from_preset("test", model="random:tiny")
    with pytest.raises(ConfigError, match="not an object placed before") as err:
        assemble(meshes["table"], [Step(meshes["cup"], "cup", "a cup on the plate", on="plate")], config,
                 base_name="table")
    assert err.value.field == "steps.0.on"
    with pytest.raises(ConfigError, match="already used"):
        assemble(meshes["table"], [Step(meshes["cup"], "table", "x")], config, base_name="table")
    with pytest.raises(ConfigError, match="stage 1/1 \\(cup\\): unknown priors provider") as err:
        assemble(meshes["table"], [Step(meshes["cup"], "cup", "x", config=config.merged(
            {"hparams_provider": "no-such-provider"}))], config, base_name="table")
    assert err.value.field == "steps.0.hparams_provider"


def test_plan_step_is_the_one_rule_of_a_step_s_shape():
    """The engine checks a plan step's keys for both adapters (``ctp assemble --plan``, ``POST /assemble``)."""
    assert plan_step({"file": "cup.glb", "image": "cup.png", "on": "plate", "options": {"seed": 1}}, "steps.1",
                     assembly_options="--preset") == PlanStep("cup.glb", image="cup.png", on="plate",
                                                              options={"seed": 1})
    assert plan_step({"file": "cup.glb", "prompt": "x", "options": None}, "steps.0", assembly_options="").options == {}
    for entry, field, message in [
        ("cup.glb", "steps.0", "a step is a mapping with file"),
        ({"prompt": "x"}, "steps.0", "a step is a mapping with file"),
        ({"file": "cup.glb", "colour": "red"}, "steps.0.colour",
         "unknown key 'colour'; known: also, file, image, name, on"),
        ({"file": "cup.glb", "name": ["cup"]}, "steps.0.name", "steps.0.name must be a string"),
        ({"file": "cup.glb", "prompt": "x", "image": "cup.png"}, "steps.0.prompt", "a prompt or an image, not both"),
        ({"file": "cup.glb", "options": [1]}, "steps.0.options", "must be a mapping of option names"),
        ({"file": "cup.glb", "options": {"model": "random:tiny"}}, "steps.0.options",
         "preset and model are set for the whole assembly (the flags)"),
    ]:
        with pytest.raises(PlanError, match=re.escape(message)) as err:
            plan_step(entry, "steps.0", assembly_options="the flags")
        assert isinstance(err.value, ConfigError) and err.value.field == field, entry


def test_cli_plan_and_add(tmp_path, meshes, capsys):
    for name, mesh in meshes.items():
        mesh.export(tmp_path / f"{name}.glb")
    (tmp_path / "plan.yaml").write_text(
        "base: table.glb\noptions: {lambda_clip: 0, steps: 120, seed: 0}\nsteps:\n"
        "  - {file: plate.glb, prompt: a plate on the table}\n"
        "  - file: cup.glb\n    prompt: a cup on the plate\n    on: plate\n")
    out = tmp_path / "scene.glb"
    code = main(["assemble", "--plan", str(tmp_path / "plan.yaml"), "--preset", "test", "--out", str(out),
                 "--report", str(tmp_path / "report.json"), "--preview", str(tmp_path / "preview.png")])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert 'stage 2/2: cup: a cup on the plate' in captured.err
    summary = json.loads(captured.out)
    assert [o["name"] for o in summary["objects"]] == ["table", "plate", "cup"]
    whole = json.loads((tmp_path / "report.json").read_text())["whole"]["relations"]
    said = summary["said"].split("; ")  # every relation of the final scene in words
    assert [line.split(": ")[0] for line in said] == ["plate on table", "cup on plate"], said
    assert all(line.split(": ")[1].startswith("holds" if r["holds"] else "does not hold")
               for line, r in zip(said, whole, strict=True)), said
    check_contacts(out.read_bytes())
    assert json.loads((tmp_path / "report.json").read_text())["stages"][1]["on"] == "plate"
    assert (tmp_path / "preview.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    code = main(["assemble", str(tmp_path / "table.glb"), "--add", str(tmp_path / "plate.glb"), "a plate on the table",
                 "--preset", "test", "--model", "random:tiny", "--out", str(tmp_path / "added.glb"), "--quiet"])
    assert code == 0
    assert list(dict(objects(load_objects(tmp_path / "added.glb")))) == ["table", "plate"]


@pytest.mark.parametrize("plan, message", [
    ("base: table.glb\nsteps:\n  - {file: cup.glb, prompt: x, on: saucer}\n", "not an object placed before"),
    ("base: table.glb\nsteps:\n  - {file: cup.glb, prompt: x, colour: red}\n", "unknown key 'colour'"),
    ("base: table.glb\nsteps:\n  - {file: cup.glb, prompt: x, options: {model: other}}\n", "whole assembly"),
    ("base: table.glb\noptions: {preset: paper}\nsteps:\n  - {file: cup.glb, prompt: x}\n", "(--preset, --model)"),
    ("base: table.glb\nsteps:\n  - {file: cup.glb, image: [cup.png]}\n", "steps.0.image must be a string"),
    ("base: table.glb\nsteps: [oops\n", "not valid YAML"),
    ("base: missing.glb\nsteps:\n  - {file: cup.glb, prompt: x}\n", "mesh_unreadable"),
])
def test_cli_refuses_a_bad_plan_with_exit_2(tmp_path, meshes, capsys, plan, message):
    for name, mesh in meshes.items():
        mesh.export(tmp_path / f"{name}.glb")
    (tmp_path / "plan.yaml").write_text(plan)
    code = main(["assemble", "--plan", str(tmp_path / "plan.yaml"), "--preset", "test", "--model", "random:tiny",
                 "--quiet", "--out", str(tmp_path / "x.glb")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and message in err[0], err


def test_table_setting_sample_is_a_valid_plan(tmp_path):
    from ctp.cmd_assemble import read_plan
    from ctp_core.io.examples import write_table_setting

    config = AlignConfig.from_preset("test", model="random:tiny")
    base, base_name, steps, _ = read_plan(write_table_setting(tmp_path), config)
    assert base_name == "table" and [(s.name, s.on, s.prompt) for s in steps] == [
        ("plate", (), "a plate on the table"), ("cup", ("plate",), "a cup on the plate")]
    assert base.extents.max() > 10 * steps[1].source.extents.max()


def test_a_yaml_plan_means_on_and_bare_numbers_as_written(tmp_path, meshes):
    """YAML 1.1 reads the key ``on:`` as true and ``name: 2`` as a number; the plan means the text."""
    from ctp.cmd_assemble import read_plan

    for name, mesh in meshes.items():
        mesh.export(tmp_path / f"{name}.glb")
    (tmp_path / "plan.yaml").write_text("base: table.glb\nsteps:\n  - {file: plate.glb, prompt: 7, name: 2}\n"
                                        "  - {file: cup.glb, prompt: x, on: 2}\n")
    _, _, steps, _ = read_plan(tmp_path / "plan.yaml", AlignConfig.from_preset("test", model="random:tiny"))
    assert [(s.name, s.prompt, s.on) for s in steps] == [("2", "7", ()), ("cup", "x", ("2",))]


def test_a_scene_keeps_its_base_s_up():
    """A plate hung at a leg's foot changes how table + plate rest (by flat bases alone, best upside down); asked
    for the geometric guess, the scene's up is still the table's own."""
    from ctp_core import orientation
    from ctp_core.assembly.assemble import Placed, scene_of
    from ctp_core.io import examples
    from ctp_core.pairs import geometry, prepare_pair

    table, plate = examples._table(), examples._plate()
    plate.apply_scale(0.96)
    hung = trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0))  # on edge at a leg, rim below the floor
    hung[:3, 3] = (-0.586, 0.046, 0.340)
    placed = scene_of([Placed("table", table, frames.Similarity(np.eye(4), frames.SCENE, frames.SCENE)),
                       Placed("plate", plate, frames.Similarity(hung, frames.SOURCE_FILE, frames.SCENE))])
    whole = orientation.orient(geometry(placed), orientation.Axes("auto"))
    table_alone = orientation.orient(table, orientation.Axes("auto"))
    assert whole.candidates != table_alone.candidates  # the plate changes the resting poses
    pair = prepare_pair(placed, examples._cup(), samples=200, seed=0, on="plate",
                        target_axes=orientation.Axes("auto"))
    assert not pair.target_upright.changed and pair.target_upright.rotation.tolist() == np.eye(3).tolist()
    assert pair.target_upright.candidates == table_alone.candidates
