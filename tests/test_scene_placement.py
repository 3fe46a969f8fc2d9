"""Placement in a scene (``assemble`` steps) on generated furniture: what keeps its up stands (a chair in front of a
desk, a sofa facing a TV stand, a rug under a desk lies flat), what stands next to or between objects on a table
stands on its top, a ground turned by its glTF node keeps the front its node gives it, and sinking is measured in
millimetres against every object and the floor (nothing ends under the floor).

Meshes are built in their file frames, +Y up, metres, the glTF front (+Z); geometry only (the test preset).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from ctp_core import orientation, pairs
from ctp_core.align import align
from ctp_core.assembly import sinking
from ctp_core.assembly.assemble import Step, assemble
from ctp_core.config import AlignConfig
from ctp_core.export import assembly_report
from ctp_core.geometry.pose import matrix_to_quaternion, quaternion_to_matrix, random_quaternions, upright_twist
from ctp_core.io import load_mesh
from ctp_core.orientation import canonical

UPRIGHT = math.cos(math.radians(5.0))  # a posed up this close to +Y stands


def box(extents, centre) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def gltf(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh.metadata["file_format"] = "glb"  # as ``io`` records a GLB: +Y up, front +Z
    return mesh


def desk() -> trimesh.Trimesh:
    """A top 1.2 x 0.6 (its upper face at 0.75) on four legs, a modesty panel at the back (-Z)."""
    pieces = [box([1.2, 0.04, 0.6], [0, 0.73, 0]), box([1.1, 0.3, 0.02], [0, 0.55, -0.28])]
    pieces += [box([0.04, 0.71, 0.04], [x, 0.355, z]) for x in (-0.57, 0.57) for z in (-0.27, 0.27)]
    return gltf(trimesh.util.concatenate(pieces))


def chair() -> trimesh.Trimesh:
    """A seat 0.45 x 0.45 on four legs, a back rising behind it (-Z) to 1.0, facing +Z."""
    pieces = [box([0.45, 0.04, 0.45], [0, 0.45, 0]), box([0.45, 0.55, 0.04], [0, 0.745, -0.205])]
    pieces += [box([0.04, 0.43, 0.04], [x, 0.215, z]) for x in (-0.2, 0.2) for z in (-0.2, 0.2)]
    return gltf(trimesh.util.concatenate(pieces))


def sofa() -> trimesh.Trimesh:
    """A seat block 2 x 0.45 x 0.9 with a backrest along -Z up to 0.9 and two arms, facing +Z."""
    pieces = [box([2.0, 0.45, 0.9], [0, 0.225, 0]), box([2.0, 0.45, 0.2], [0, 0.675, -0.35])]
    pieces += [box([0.15, 0.2, 0.9], [x, 0.55, 0]) for x in (-0.925, 0.925)]
    return gltf(trimesh.util.concatenate(pieces))


def tv_stand() -> trimesh.Trimesh:
    return gltf(box([1.4, 0.5, 0.4], [0, 0.25, 0]))


def table() -> trimesh.Trimesh:
    """A top 1.2 x 0.8 (its upper face at 0.75) on four legs."""
    pieces = [box([1.2, 0.04, 0.8], [0, 0.73, 0])]
    pieces += [box([0.05, 0.71, 0.05], [x, 0.355, z]) for x in (-0.55, 0.55) for z in (-0.35, 0.35)]
    return gltf(trimesh.util.concatenate(pieces))


def standing_cylinder(radius: float, height: float) -> trimesh.Trimesh:
    """A cup, a mug or a bowl: a closed cylinder standing on y = 0."""
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=24)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    mesh.apply_translation((0.0, height / 2, 0.0))
    return gltf(mesh)


def config() -> AlignConfig:
    return AlignConfig.from_preset("test", model="random:tiny", seed=0, loss={"lambda_clip": 0.0})


def placed(assembly, name: str) -> trimesh.Trimesh:
    """An object of the assembly where it stands in the scene."""
    entry = next(p for p in assembly.objects if p.name == name)
    return entry.mesh.copy().apply_transform(np.asarray(entry.to_scene.matrix))


def up_of(assembly, name: str) -> float:
    """The +Y component of the object's own up (its file's +Y) as placed: 1 standing, -1 upside down."""
    entry = next(p for p in assembly.objects if p.name == name)
    rotation = np.asarray(entry.to_scene.matrix)[:3, :3]
    rotation = rotation / np.cbrt(np.linalg.det(rotation))
    return float(rotation[1, 1])


# --- what keeps its up -----------------------------------------------------------------------------------------


def test_a_clear_up_is_legs_or_a_real_base_not_a_tip():
    assert canonical.clear_up(chair(), np.array([0.0, 1.0, 0.0]))[0]  # on legs
    assert canonical.clear_up(sofa(), np.array([0.0, 1.0, 0.0]))[0]  # on a base
    assert canonical.clear_up(gltf(box([1.6, 0.01, 1.0], [0, 0, 0])), np.array([0.0, 1.0, 0.0]))[0]  # a rug, flat
    cone = trimesh.creation.cone(radius=0.2, height=0.5)  # its +Z up from the tip: +Z down stands on the tip
    assert not canonical.clear_up(cone, np.array([0.0, 0.0, -1.0]))[0]
    assert not canonical.clear_up(table(), np.array([0.0, -1.0, 0.0]))[0]  # on its top, legs up


def test_the_upright_twist_keeps_the_up_and_only_the_turn_about_it():
    up = trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0))[:3, :3]  # a Z-up source's upright turn
    q_up = torch.as_tensor(matrix_to_quaternion(up), dtype=torch.float32)
    twisted = upright_twist(random_quaternions(64, torch.Generator().manual_seed(0)), q_up)
    own_up = torch.as_tensor(up.T @ np.array([0.0, 1.0, 0.0]), dtype=torch.float32)
    assert torch.allclose(quaternion_to_matrix(twisted) @ own_up, torch.tensor([0.0, 1.0, 0.0]), atol=1e-5)
    yaw = torch.tensor([[math.cos(0.3), 0.0, math.sin(0.3), 0.0]])
    standing = torch.as_tensor(matrix_to_quaternion(np.asarray(quaternion_to_matrix(yaw)[0]) @ up),
                               dtype=torch.float32)[None]
    assert torch.allclose(quaternion_to_matrix(upright_twist(standing, q_up)), quaternion_to_matrix(standing),
                          atol=1e-5)  # already standing: unchanged


def test_a_chair_in_front_of_a_desk_stands_upright():
    done = assemble(desk(), [Step(chair(), "chair", "a chair in front of the desk", on="desk")], config(),
                    base_name="desk")
    assert up_of(done, "chair") > UPRIGHT
    assert done.results[0].result.relation["holds"] and done.whole["all_hold"], done.whole
    chair_bounds = placed(done, "chair").bounds
    assert chair_bounds[0][2] > 0.25  # in front: past the desk's front face (z = 0.3), 5 cm of overlap allowed
    assert chair_bounds[0][1] >= -1e-6  # nothing under the floor (the desk's feet)
    stage = assembly_report(done)["stages"][0]
    assert stage["keeps_up"] == {"kept": True, "why": "it stands on 4 legs with that up"}, stage.get("keeps_up")


def test_a_sofa_facing_a_tv_stand_stands_upright():
    done = assemble(tv_stand(), [Step(sofa(), "sofa", "the sofa facing the TV stand", on="TV stand")], config(),
                    base_name="TV stand")
    assert up_of(done, "sofa") > UPRIGHT
    assert placed(done, "sofa").bounds[0][1] >= -1e-6


def test_a_rug_under_a_desk_lies_flat():
    rug = gltf(box([1.0, 0.01, 0.5], [0, 0, 0]))
    done = assemble(desk(), [Step(rug, "rug", "a rug under the desk", on="desk")], config(), base_name="desk")
    assert up_of(done, "rug") > UPRIGHT  # flat: not stood on its edge
    assert placed(done, "rug").extents[1] < 0.02


def test_a_single_pair_is_left_free():
    """Outside a scene step nothing is locked: a pair's benchmarks turn sources over on purpose."""
    pair = pairs.prepare_pair(desk(), chair(), samples=200, seed=0, keep_up=False)
    assert not pair.source_keeps_up
    locked = pairs.prepare_pair(trimesh.Scene({"desk": desk()}), chair(), samples=200, seed=0, keep_up=True)
    assert locked.source_keeps_up and "legs" in locked.source_up_why


# --- on the same surface ---------------------------------------------------------------------------------------


def test_a_cup_beside_a_mug_on_a_table_stands_on_the_table_top():
    steps = [Step(standing_cylinder(0.045, 0.1), "mug", "a mug on the table", on="table"),
             Step(standing_cylinder(0.04, 0.09), "cup", "a cup beside the mug", on="mug")]
    done = assemble(table(), steps, config(), base_name="table")
    cup, mug = placed(done, "cup"), placed(done, "mug")
    assert abs(mug.bounds[0][1] - 0.75) < 0.01
    assert abs(cup.bounds[0][1] - 0.75) < 0.01, cup.bounds  # on the top, not on the floor under the table
    assert done.whole["relations"][1]["holds"], done.whole


def _cups_on_a_table() -> trimesh.Scene:
    scene = trimesh.Scene()
    scene.add_geometry(table(), node_name="table", geom_name="table")
    for name, x in (("cup_1", -0.35), ("cup_2", 0.35)):
        scene.add_geometry(standing_cylinder(0.04, 0.09), node_name=name, geom_name=name,
                           transform=trimesh.transformations.translation_matrix((x, 0.75, 0.1)))
    return scene


def test_the_floor_of_a_step_is_the_level_its_grounds_stand_at():
    scene = _cups_on_a_table()
    pair = pairs.prepare_pair(scene, standing_cylinder(0.08, 0.06), samples=200, seed=0, on=["cup_1", "cup_2"])
    top = pair.target_to_normalised.apply(np.array([[0.0, 0.75, 0.0]]))[0, 1]
    bottom = pair.target_to_normalised.apply(np.array([[0.0, 0.0, 0.0]]))[0, 1]
    assert pair.floor == pytest.approx(top, abs=1e-4) and pair.scene_floor == pytest.approx(bottom, abs=1e-4)
    whole = pairs.prepare_pair(scene, standing_cylinder(0.08, 0.06), samples=200, seed=0)
    assert whole.floor == pytest.approx(bottom, abs=1e-4)  # no ground named: the scene's floor


def test_a_bowl_between_two_cups_on_a_table_stands_on_the_top():
    bowl = standing_cylinder(0.08, 0.06)
    result = align(_cups_on_a_table(), bowl, "a bowl between cup_1 and cup_2", config(), on=["cup_1", "cup_2"],
                   target_name="cup_1", source_name="bowl")
    bounds = bowl.copy().apply_transform(result.source_to_target).bounds
    assert result.relation["holds"], result.relation
    assert abs(bounds[0][1] - 0.75) < 0.01, bounds  # level with the cups' bottoms
    assert -0.31 < bounds.mean(0)[0] < 0.31  # between them


# --- fronts a node gives ---------------------------------------------------------------------------------------


def _glb(mesh: trimesh.Trimesh, path, rotation: np.ndarray) -> None:
    scene = trimesh.Scene()
    scene.add_geometry(mesh, node_name="desk", geom_name="desk", transform=rotation)
    path.write_bytes(scene.export(file_type="glb"))


def test_a_desk_turned_by_its_node_keeps_the_front_its_node_gives(tmp_path):
    _glb(desk(), tmp_path / "desk.glb", trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    loaded = load_mesh(tmp_path / "desk.glb")
    assert np.allclose(loaded.metadata["front"], [1.0, 0.0, 0.0], atol=1e-6)  # its +Z turned 90 degrees: +X
    frame = orientation.orient(loaded)
    assert np.allclose(frame.front, [1.0, 0.0, 0.0], atol=1e-6) and frame.front_trusted
    done = assemble(loaded, [Step(chair(), "chair", "a chair in front of the desk", on="desk")], config(),
                    base_name="desk")
    centre = placed(done, "chair").bounds.mean(0)
    assert centre[0] > 0.3 and abs(centre[2]) < 0.6, centre  # at its turned front (+X), not at its side (+Z)
    assert up_of(done, "chair") > UPRIGHT


def test_a_z_up_export_behind_a_node_turn_keeps_plus_z_as_its_front(tmp_path):
    """Exports from Z-up tools turn the root -90 degrees about X: the flattened +Z is then the front already."""
    z_up = desk().apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    _glb(z_up, tmp_path / "desk.glb", trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    loaded = load_mesh(tmp_path / "desk.glb")
    assert "front" not in loaded.metadata
    assert np.allclose(orientation.orient(loaded).front, [0.0, 0.0, 1.0])


def test_a_ground_placed_turned_in_a_scene_is_read_in_its_own_frame():
    """A lamp "to the left of the sofa" once the sofa was turned to face the TV: the sofa's front, not the base's."""
    scene = trimesh.Scene()
    scene.add_geometry(tv_stand(), node_name="TV stand", geom_name="TV stand")
    turn = trimesh.transformations.rotation_matrix(np.pi, (0, 1, 0))
    turn[:3, 3] = (0.0, 0.0, 2.0)
    scene.add_geometry(sofa(), node_name="sofa", geom_name="sofa", transform=turn)
    pair = pairs.prepare_pair(scene, box([0.3, 1.6, 0.3], [0, 0.8, 0]), samples=200, seed=0, on="sofa")
    front = pair.target_to_normalised.inverse().apply_directions(pair.target_front[None])[0]
    assert np.allclose(front / np.linalg.norm(front), [0.0, 0.0, -1.0], atol=1e-6) and pair.front_trusted


# --- sinking ---------------------------------------------------------------------------------------------------


def test_a_5_mm_sink_is_reported_as_5_mm_and_a_drop_under_the_floor_as_its_depth():
    crate = box([0.3, 0.3, 0.3], [0, 0, 0])
    on_top = trimesh.transformations.translation_matrix((0.0, 0.75 + 0.15 - 0.005, 0.0))
    sunk = sinking.sinking("crate", crate, on_top, [("table", table(), np.eye(4))], floor=0.0)
    assert sunk.to_dict()["penetration_mm"] == pytest.approx(5.0, abs=0.3) and sunk.into == "table"
    assert sunk.sunk(0.52)
    resting = trimesh.transformations.translation_matrix((0.0, 0.75 + 0.15 + 0.0005, 0.0))
    clear = sinking.sinking("crate", crate, resting, [("table", table(), np.eye(4))], floor=0.0)
    assert clear.to_dict() == {"penetration_mm": 0.0, "into": None, "below_floor_mm": 0.0} and not clear.sunk(0.52)
    under = trimesh.transformations.translation_matrix((1.0, 0.15 - 0.02, 0.0))
    assert sinking.sinking("crate", crate, under, [], floor=0.0).to_dict()["below_floor_mm"] == pytest.approx(20.0)


def test_the_whole_scene_reports_millimetres_and_nothing_ends_under_the_floor():
    steps = [Step(standing_cylinder(0.045, 0.1), "mug", "a mug on the table", on="table"),
             Step(chair(), "chair", "a chair in front of the table", on="table")]
    done = assemble(table(), steps, config(), base_name="table")
    for verdict in done.whole["relations"]:
        assert {"penetration_mm", "into", "below_floor_mm"} <= set(verdict)
        assert verdict["below_floor_mm"] == 0.0
        assert verdict["penetration_mm"] <= 1000 * sinking.SINK or verdict["intersects"]
    for name in ("mug", "chair"):
        assert placed(done, name).bounds[0][1] >= -1e-6


def test_a_step_sunk_into_what_it_rests_on_with_no_clean_alternative_is_raised_out_of_it():
    """A cushion whose every placement is 2 cm into the sofa's seat: none is clean, so the least bad is raised by
    its measured depth and kept resting on the seat; the record says so."""
    from dataclasses import replace

    from ctp_core.assembly.assemble import _keeping, judged

    cushion = gltf(box([0.4, 0.12, 0.4], [0, 0, 0]))
    done = assemble(sofa(), [Step(cushion, "cushion", "a cushion on the sofa", on="sofa")], config(),
                    base_name="sofa")
    answer = done.results[0].result
    sunk = np.array(answer.source_to_target)
    sunk[1, 3] -= 0.02
    entry = {"source_to_target": sunk.tolist(), "objective": answer.objective, "restart": answer.best_restart,
             "relation": answer.relation}
    bad = replace(answer, source_to_target=sunk, alternatives=[entry, entry])
    kept, record = _keeping(done.objects[:1], [], done.results[0].step, bad, ["sofa"])
    assert record["lifted"] and any("sinks" in b for b in record["broke"]), record
    lifted = cushion.copy().apply_transform(kept.source_to_target)
    assert lifted.bounds[0][1] == pytest.approx(placed(done, "cushion").bounds[0][1], abs=0.004)
    moved = [done.objects[0], replace(done.objects[1], to_scene=replace(done.objects[1].to_scene, matrix=sunk))]
    assert judged(moved, done.results)["relations"][0]["penetration_mm"] == pytest.approx(20.0, abs=3.0)
