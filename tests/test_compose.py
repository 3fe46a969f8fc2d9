"""``ctp compose``: a described scene of generated furniture placed end to end (geometry only, the test preset),
every relation judged again on the final scene; the plan printed by ``--dry-run`` runs as ``ctp assemble --plan``;
an object the description names without an upload is one line and exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
import yaml

from ctp.cli import main
from ctp_core.assembly.describe import read_description

DESCRIPTION = "a workbench, a toolbox on it, a stool to its left and two paint tins under it"
RUN = ["--preset", "test", "--no-guidance", "--seed", "0", "--quiet"]


def _box(x: float, y: float, z: float, at: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """A box standing on y = at[1] (+Y up, the glTF convention)."""
    box = trimesh.creation.box((x, y, z))
    box.apply_translation((at[0], at[1] + y / 2, at[2]))
    return box


def _bench(width: float = 1.4, height: float = 0.9, depth: float = 0.7, top: float = 0.05, leg: float = 0.06
           ) -> trimesh.Trimesh:
    """A workbench: a top on four legs, room under it."""
    legs = [_box(leg, height - top, leg, (sx * (width - leg) / 2, 0.0, sz * (depth - leg) / 2))
            for sx in (-1, 1) for sz in (-1, 1)]
    return trimesh.util.concatenate([_box(width, top, depth, (0.0, height - top, 0.0)), *legs])


@pytest.fixture(scope="module")
def props(tmp_path_factory):
    """workbench.glb, toolbox.glb, stool.glb and paint_tin.glb (metres, +Y up)."""
    folder = tmp_path_factory.mktemp("props")
    meshes = {"workbench": _bench(), "toolbox": _box(0.45, 0.25, 0.2), "stool": _box(0.5, 0.45, 0.35),
              "paint_tin": _box(0.18, 0.2, 0.18)}
    for name, mesh in meshes.items():
        mesh.export(folder / f"{name}.glb")
    return folder


def _files(props) -> list[str]:
    return [str(props / f"{name}.glb") for name in ("workbench", "toolbox", "stool", "paint_tin")]


def test_a_described_scene_of_five_objects_holds_every_relation(props, tmp_path, capsys):
    out, report = tmp_path / "scene.glb", tmp_path / "report.json"
    assert main(["compose", *_files(props), "--prompt", DESCRIPTION, *RUN, "--out", str(out),
                 "--report", str(report)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert [s["name"] for s in summary["plan"]["steps"]] == ["toolbox", "stool", "paint tin_1", "paint tin_2"]
    written = json.loads(report.read_text())
    whole = written["whole"]
    assert [(r["name"], r["relation"], r["on"]) for r in whole["relations"]] == [
        ("toolbox", "on", ["workbench"]), ("stool", "left", ["workbench"]),
        ("paint tin_1", "under", ["workbench"]), ("paint tin_2", "under", ["workbench"])]
    assert all(r["holds"] for r in whole["relations"]), whole
    assert whole["all_hold"] and whole["none_intersect"]
    scene = trimesh.load(out)
    assert sorted(scene.graph.nodes_geometry) == ["paint tin_1", "paint tin_2", "stool", "toolbox", "workbench"]
    base, _ = scene.graph["workbench"]
    assert base == pytest.approx(np.eye(4))  # the first object named as a ground stays in its file frame


def test_dry_run_prints_a_plan_ctp_assemble_runs(props, tmp_path, capsys):
    assert main(["compose", *_files(props)[:3], "--names", "bench", "box", "seat", "--prompt",
                 "put the box on the bench; stand the seat in front of it", "--dry-run"]) == 0
    printed = capsys.readouterr().out
    plan = yaml.safe_load(printed)
    assert plan["base"].endswith("workbench.glb") and plan["name"] == "bench"
    assert [(s["name"], s["on"]) for s in plan["steps"]] == [("box", "bench"), ("seat", "bench")]  # "it": the bench
    assert "# 2. seat: front bench" in printed
    path = tmp_path / "plan.yaml"
    path.write_text(printed.replace(str(props) + "/", ""))
    for name in ("workbench", "toolbox", "stool"):
        (tmp_path / f"{name}.glb").write_bytes((props / f"{name}.glb").read_bytes())
    assert main(["assemble", "--plan", str(path), *RUN, "--out", str(tmp_path / "scene.glb")]) == 0
    assert [o["name"] for o in json.loads(capsys.readouterr().out)["objects"]] == ["bench", "box", "seat"]


def test_an_object_with_no_upload_is_one_line_and_exit_2(props, capsys):
    code = main(["compose", *_files(props)[:2], "--prompt", "a workbench with a metronome on it", *RUN])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.count("\n") == 0
    assert err.startswith("error: unknown_object: 'metronome'")


def test_names_must_be_one_per_object(props, capsys):
    assert main(["compose", *_files(props)[:2], "--names", "bench", "--prompt", "a box on the bench"]) == 2
    assert capsys.readouterr().err.startswith("error: invalid_option: --names gives 1 names for 2 objects")


def test_the_plan_names_nodes_as_the_uploads():
    plan = read_description(DESCRIPTION, ["Workbench", "ToolBox", "Stool", "Paint_Tin"])
    assert plan.base == "Workbench" and [s.name for s in plan.steps] == [
        "ToolBox", "Stool", "Paint_Tin_1", "Paint_Tin_2"]


def test_a_step_that_breaks_an_earlier_relation_is_retried_among_its_alternatives(props):
    """The stool's answer moved into the toolbox breaks "toolbox on workbench" and intersects: its run's next
    alternative (where the stool really is) is kept instead, and the record says what the answer broke."""
    from dataclasses import replace

    from ctp.cli import command_parser
    from ctp.cmd_align import config_from_args
    from ctp_core.assembly.assemble import Step, _keeping, assemble, judged
    from ctp_core.assembly.describe import read_description as read_plan

    meshes = [trimesh.load(props / f"{n}.glb", force="mesh") for n in ("workbench", "toolbox", "stool")]
    plan = read_plan("a toolbox on the workbench and a stool to its left", ["workbench", "toolbox", "stool"])
    config = config_from_args(command_parser("compose")[1].parse_args(["x", "--prompt", "x", *RUN]))
    steps = [Step(source=meshes[s.upload], name=s.name, prompt=s.prompt, on=list(s.on)) for s in plan.steps]
    done = assemble(meshes[0], steps, config, base_name="workbench")
    # a step may already have been retried (its answer sunk into the workbench past ``sinking.SINK``): then the
    # answer raised out of it, or an alternative that breaks nothing, was kept; or its answer, breaking nothing,
    # was dropped into contact with what it stands on
    assert done.whole["all_hold"] and done.whole["none_intersect"]
    assert all(s.kept is None or s.kept["alternative"] > 0 or s.kept.get("lifted") or s.kept.get("dropped")
               for s in done.results)
    toolbox, stool = done.objects[1], done.results[1]
    into = np.array(stool.result.source_to_target)
    into[:3, 3] = toolbox.to_scene.translation  # the stool where the toolbox is
    good = {"source_to_target": stool.result.source_to_target.tolist(), "objective": stool.result.objective,
            "restart": stool.result.best_restart, "relation": stool.result.relation}
    bad = replace(stool.result, source_to_target=into, alternatives=[{**good, "source_to_target": into.tolist()},
                                                                      good])
    kept, record = _keeping(done.objects[:2], done.results[:1], steps[1], bad, ["workbench"])
    assert np.allclose(kept.source_to_target, stool.result.source_to_target)
    assert record["alternative"] == 1 and any("toolbox on workbench" in b for b in record["broke"])
    moved = [*done.objects[:2], replace(done.objects[2], to_scene=replace(done.objects[2].to_scene, matrix=into))]
    assert judged(moved, done.results)["none_intersect"] is False
