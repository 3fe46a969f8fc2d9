"""A step with two grounds ("a lamp between the sofa and the armchair") through the assembly layers: the plan's
``on`` as a name or a list (``plan_step``, ``check_plan``, a YAML plan), and ``ctp assemble`` placing a sofa, an
armchair away from it ("far": room for a lamp between them; "beside" stands it a hand's width away, its usual
place) and a lamp between the two, geometry only: the report names both grounds, the relation's verdict holds, and
the GLB as written has the lamp between them without entering either."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import trimesh

from ctp.cli import main
from ctp_core.assembly.plan import PlanError, PlanStep, check_plan, plan_step
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.io import load_objects
from ctp_core.pairs import objects

LAMP_PROMPT = "a lamp between the sofa and the armchair"
DEPTH_M = 0.01  # deepest point of the lamp inside the sofa or the armchair (boxes of 0.8 to 2 m)


def sofa_armchair_lamp() -> dict[str, trimesh.Trimesh]:
    """Two boxes and a 30 cm wide floor lamp, each in its own arbitrary file pose."""
    sofa = trimesh.creation.box((2.0, 0.8, 0.9))
    sofa.apply_translation((0.0, 0.4, 0.0))
    armchair = trimesh.creation.box((0.9, 0.8, 0.9))
    armchair.apply_translation((4.0, 1.0, 2.0))
    lamp = trimesh.creation.cylinder(radius=0.15, height=1.2, sections=16)
    lamp.apply_translation((5.0, 0.6, 3.0))
    return {"sofa": sofa, "armchair": armchair, "lamp": lamp}


def test_a_step_s_on_is_a_name_or_a_list_of_two():
    assert plan_step({"file": "lamp.glb", "prompt": LAMP_PROMPT, "on": ["sofa", "armchair"]}, "steps.2",
                     assembly_options="") == PlanStep("lamp.glb", prompt=LAMP_PROMPT, on=("sofa", "armchair"))
    assert plan_step({"file": "cup.glb", "prompt": "x", "on": "plate"}, "steps.0", assembly_options="").on == (
        "plate",)
    assert plan_step({"file": "cup.glb", "prompt": "x", "on": ["plate"]}, "steps.0", assembly_options="").on == (
        "plate",)
    assert plan_step({"file": "cup.glb", "prompt": "x"}, "steps.0", assembly_options="").on == ()
    assert PlanStep("cup.glb", on="plate") == PlanStep("cup.glb", on=("plate",))
    for on, message in [
        (["sofa", "armchair", "table"], "steps.0.on must be a name or a list of 1 to 2 names"),
        ([], "steps.0.on must be a name or a list of 1 to 2 names"),
        (["sofa", 2], "steps.0.on must be a name or a list of 1 to 2 names"),
        (5, "steps.0.on must be a name or a list of 1 to 2 names"),
        ({"sofa": 1}, "steps.0.on must be a name or a list of 1 to 2 names"),
        (["sofa", "sofa"], "steps.0.on names 'sofa' twice"),
    ]:
        with pytest.raises(PlanError, match=re.escape(message)) as err:
            plan_step({"file": "lamp.glb", "prompt": LAMP_PROMPT, "on": on}, "steps.0", assembly_options="")
        assert err.value.field == "steps.0.on", on


def test_every_ground_is_placed_before_its_step():
    check_plan("sofa", [("armchair", ("sofa",), True), ("lamp", ("sofa", "armchair"), True)])
    check_plan("sofa", [("armchair", (), True), ("lamp", "armchair", True)])  # a plain name still reads as one
    with pytest.raises(ConfigError, match="step 2 \\(lamp\\): on 'table' is not an object placed before it") as err:
        check_plan("sofa", [("armchair", ("sofa",), True), ("lamp", ("sofa", "table"), True)])
    assert err.value.field == "steps.1.on"
    with pytest.raises(ConfigError, match="on 'lamp' is not an object placed before it") as err:
        check_plan("sofa", [("lamp", ("sofa", "lamp"), True)])  # not itself either
    assert err.value.field == "steps.0.on"


def test_a_yaml_plan_takes_a_list_of_grounds(tmp_path):
    """``on: [a, b]`` under YAML 1.1 (the key ``on`` reads as true, bare numbers as numbers) means the names."""
    from ctp.cmd_assemble import read_plan

    for name, mesh in sofa_armchair_lamp().items():
        mesh.export(tmp_path / f"{name}.glb")
    (tmp_path / "plan.yaml").write_text(
        "base: sofa.glb\nsteps:\n  - {file: armchair.glb, prompt: an armchair far from the sofa, name: 2}\n"
        f"  - file: lamp.glb\n    prompt: {LAMP_PROMPT}\n    on: [sofa, 2]\n")
    _, _, steps, _ = read_plan(tmp_path / "plan.yaml", AlignConfig.from_preset("test", model="random:tiny"))
    assert [(s.name, s.on) for s in steps] == [("2", ()), ("lamp", ("sofa", "2"))]
    (tmp_path / "bad.yaml").write_text("base: sofa.glb\nsteps:\n  - {file: lamp.glb, prompt: x, on: [a, b, c]}\n")
    with pytest.raises(PlanError, match="steps.0.on must be a name or a list of 1 to 2 names"):
        read_plan(tmp_path / "bad.yaml", AlignConfig.from_preset("test", model="random:tiny"))


@pytest.mark.parametrize("plan, message", [
    (f"  - {{file: lamp.glb, prompt: {LAMP_PROMPT}, on: [sofa, table]}}\n", "on 'table' is not an object placed"),
    (f"  - {{file: lamp.glb, prompt: {LAMP_PROMPT}, on: [sofa, sofa]}}\n", "steps.0.on names 'sofa' twice"),
])
def test_cli_refuses_a_bad_list_of_grounds_with_exit_2(tmp_path, capsys, plan, message):
    for name, mesh in sofa_armchair_lamp().items():
        mesh.export(tmp_path / f"{name}.glb")
    (tmp_path / "plan.yaml").write_text("base: sofa.glb\nsteps:\n" + plan)
    code = main(["assemble", "--plan", str(tmp_path / "plan.yaml"), "--preset", "test", "--model", "random:tiny",
                 "--quiet", "--out", str(tmp_path / "x.glb")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0], err


def check_between(glb: bytes) -> None:
    """The lamp, as written, lies between the sofa and the armchair (its centre projects inside the segment of
    their centres, nearer that segment than either box's half width) and enters neither."""
    placed = dict(objects(load_objects(glb, filename="scene.glb")))
    assert list(placed) == ["sofa", "armchair", "lamp"]
    a, b = placed["sofa"].bounds.mean(0), placed["armchair"].bounds.mean(0)
    c = placed["lamp"].bounds.mean(0)
    t = float(np.dot(c - a, b - a) / np.dot(b - a, b - a))
    assert 0.0 < t < 1.0, f"the lamp is not between them along the line of their centres (t={t:.2f})"
    off_line = np.linalg.norm(c - (a + t * (b - a)))
    assert off_line < 0.45, f"the lamp is {off_line:.2f} m off the line between them"
    points = trimesh.sample.sample_surface(placed["lamp"], 2000, seed=0)[0]
    for ground in ("sofa", "armchair"):
        depth = trimesh.proximity.signed_distance(placed[ground], points).max()  # > 0 inside
        assert depth < DEPTH_M, f"the lamp is {depth:.4f} m inside the {ground}"


def test_cli_add_places_a_lamp_between_two_placed_objects(tmp_path, capsys):
    """``--add`` names no grounds: the between prompt finds its two among the placed objects."""
    for name, mesh in sofa_armchair_lamp().items():
        mesh.export(tmp_path / f"{name}.glb")
    out, report = tmp_path / "room.glb", tmp_path / "report.json"
    code = main(["assemble", str(tmp_path / "sofa.glb"),
                 "--add", str(tmp_path / "armchair.glb"), "an armchair far from the sofa",
                 "--add", str(tmp_path / "lamp.glb"), LAMP_PROMPT,
                 "--preset", "test", "--model", "random:tiny", "--no-guidance", "--seed", "0",
                 "--out", str(out), "--report", str(report), "--quiet"])
    assert code == 0, capsys.readouterr().err
    stages = json.loads(report.read_text())["stages"]
    assert [(s["name"], s["on"], s["grounds"]) for s in stages] == [
        ("armchair", "sofa", ["sofa"]), ("lamp", "sofa", ["sofa", "armchair"])]
    lamp = stages[1]
    assert lamp["relation"]["name"] == "between" and lamp["relation"]["holds"], lamp["relation"]
    assert lamp["extra"]["grounds"] == ["sofa", "armchair"]
    check_between(out.read_bytes())


def test_assemble_takes_the_two_grounds_a_step_names():
    """Grounds given as a list, in the step's order, are the ones the run relates the lamp to and reports."""
    from ctp_core.assembly.assemble import Step, assemble
    from ctp_core.export import assembly_glb, assembly_report

    meshes = sofa_armchair_lamp()
    config = AlignConfig.from_preset("test", model="random:tiny", seed=0, loss={"lambda_clip": 0.0})
    assembly = assemble(meshes["sofa"], [Step(meshes["armchair"], "armchair", "an armchair far from the sofa"),
                                         Step(meshes["lamp"], "lamp", LAMP_PROMPT, on=("armchair", "sofa"))],
                        config, base_name="sofa")
    lamp = json.loads(json.dumps(assembly_report(assembly)))["stages"][1]
    assert (lamp["on"], lamp["grounds"], lamp["extra"]["grounds"]) == ("armchair", ["armchair", "sofa"],
                                                                        ["armchair", "sofa"])
    assert lamp["relation"]["name"] == "between" and lamp["relation"]["holds"], lamp["relation"]
    assert "armchair" in lamp["hparams"]["reason"]  # the priors read the first ground's name
    check_between(assembly_glb(assembly))
