"""Up and front come from the file first (``orientation``); ``auto`` stands legged things on their legs."""

from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from ctp_core import align as stages
from ctp_core import io, orientation
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.orientation import canonical


def _box(extents, at) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents).apply_translation(at)


def _upright_y(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """trimesh's cylinders run along z; stand one along +y."""
    return mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))


def table() -> trimesh.Trimesh:
    """A table authored on its legs (+Y up): a 1.6 x 0.9 top at 0.75, four thin legs."""
    legs = [_box((0.06, 0.7, 0.06), (x, 0.35, z)) for x in (-0.75, 0.75) for z in (-0.4, 0.4)]
    return trimesh.util.concatenate([_box((1.6, 0.06, 0.9), (0, 0.72, 0)), *legs])


def stool() -> trimesh.Trimesh:
    """A round seat on three round legs."""
    seat = _upright_y(trimesh.creation.cylinder(radius=0.2, height=0.04, sections=32)).apply_translation([0, 0.62, 0])
    legs = [_upright_y(trimesh.creation.cylinder(radius=0.02, height=0.6, sections=12))
            .apply_translation([0.15 * np.cos(a), 0.3, 0.15 * np.sin(a)]) for a in np.arange(3) * 2 * np.pi / 3]
    return trimesh.util.concatenate([seat, *legs])


def animal() -> trimesh.Trimesh:
    """A four-legged box "animal": a body, a head in front and above, four legs at the body's corners."""
    legs = [_box((0.1, 0.4, 0.1), (x, 0.2, z)) for x in (-0.42, 0.42) for z in (-0.14, 0.14)]
    return trimesh.util.concatenate([_box((1.0, 0.35, 0.4), (0, 0.55, 0)), _box((0.3, 0.3, 0.3), (0.6, 0.8, 0)), *legs])


def _turned(mesh: trimesh.Trimesh, rotation: np.ndarray) -> trimesh.Trimesh:
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    return mesh.copy().apply_transform(matrix)


def _file(mesh: trimesh.Trimesh, path) -> trimesh.Trimesh:
    """``mesh`` written to ``path`` and read back as an upload is (its format recorded)."""
    mesh.export(path)
    return io.load_mesh(path)


@pytest.mark.parametrize("make", [table, stool, animal])
@pytest.mark.parametrize("turn", [("x", 180), ("z", 180), ("xz", (30, 150)), ("zx", (-20, 200))])
def test_auto_stands_legged_furniture_and_animals_on_their_legs(make, turn):
    """Upside down or tilted: ``up: auto`` finds the authored +Y (the top is a better flat base than the leg tips,
    which is how the old rule turned tables over, and kept them so); authored upright, the file stays as it is."""
    rotation = Rotation.from_euler(turn[0], turn[1], degrees=True).as_matrix()
    found = orientation.orient(_turned(make(), rotation), orientation.Axes("auto"))
    assert found.changed and "legs" in found.reason, found.reason
    authored_up = rotation.T @ found.up
    assert authored_up[1] > np.cos(np.radians(5.0)), (authored_up, found.reason)
    kept = orientation.orient(make(), orientation.Axes("auto"))
    assert not kept.changed and "on legs" in kept.reason


def test_a_table_lying_on_its_side_in_its_file_stays_so():
    """An authored resting pose that is no flat top down is kept (the safer error: the run still places in the
    file's frame, and ``up`` can say otherwise)."""
    lying = orientation.orient(_turned(table(), Rotation.from_euler("x", 90, degrees=True).as_matrix()),
                               orientation.Axes("auto"))
    assert not lying.changed and "already upright" in lying.reason


@pytest.mark.parametrize("make", [table, stool])
def test_the_legs_cue_counts_feet(make):
    """Standing, the surface near the floor falls into one piece per leg; upside down, one piece (the top)."""
    poses = canonical.resting_poses(canonical.unit_size(make()))
    standing = next(p for p in poses if p["up"][1] > 0.99)
    flipped = next(p for p in poses if p["up"][1] < -0.99)
    assert standing["feet"] == (3 if make is stool else 4)
    assert flipped["feet"] == 1


def test_feet_are_counted_when_read_and_survive_copies():
    """A resting pose's feet are counted on first read (``canonical._Resting``): a copy or a pickle made before
    counts the same; a table upside down is clearly not up (its legs are opposite), counting those poses' feet."""
    poses = canonical.resting_poses(canonical.unit_size(table()))
    standing = next(p for p in poses if p["up"][1] > 0.99)
    assert "feet" not in standing
    twins = copy.deepcopy(standing), pickle.loads(pickle.dumps(standing))
    assert [standing["feet"], *(t["feet"] for t in twins)] == [4, 4, 4]
    with pytest.raises(KeyError):
        standing["legs"]
    clear, why = canonical.clear_up(canonical.unit_size(table()), np.array([0.0, -1.0, 0.0]), stated=True)
    assert not clear and "legs on its other side" in why


def test_a_gltf_asset_is_never_turned_without_up_auto(tmp_path):
    """An upside-down table in a glTF: target and source keep +Y up and +Z front (the spec's), through ``align``'s
    prepare stage as well; ``auto`` (asked for) stands it on its legs."""
    flipped = _file(_turned(table(), Rotation.from_euler("x", 180, degrees=True).as_matrix()),
                    tmp_path / "table.glb")
    cup = _file(_upright_y(trimesh.creation.cylinder(radius=0.08, height=0.2, sections=24)), tmp_path / "cup.glb")
    assert flipped.metadata["file_format"] == "glb"
    kept = orientation.orient(flipped)
    assert not kept.changed and "every glTF file" in kept.reason
    assert np.allclose(kept.front, [0, 0, 1]) and kept.front_trusted
    config = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0})
    run = stages.prepare(flipped, cup, "a cup on the table", config, target_name="table", source_name="cup")
    assert not run.pair.target_upright.changed and not run.pair.source_upright.changed
    np.testing.assert_allclose(run.pair.target_front, [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(run.pair.source_front, [0, 0, 1], atol=1e-9)
    assert run.pair.front_trusted  # a table is not symmetric about its up
    asked = stages.prepare(flipped, cup, "a cup on the table", config.model_copy(update={"target_up": "auto"}),
                           target_name="table", source_name="cup")
    assert asked.pair.target_upright.changed and asked.pair.target_upright.up[1] < -0.99


def test_a_symmetric_gltf_target_has_no_trusted_front(tmp_path):
    vase = _file(_upright_y(trimesh.creation.cylinder(radius=0.3, height=1.0, sections=48)), tmp_path / "vase.glb")
    frame = orientation.orient(vase)
    assert not frame.changed and not frame.front_trusted and "symmetric" in frame.front_reason


def test_formats_without_a_convention_follow_the_stated_rule(tmp_path):
    """OBJ, STL, PLY: Y-up, unless the object stands on legs with the file's +Z up only (a Z-up export); the front
    is then -Y (Blender's), and never trusted; the rule never turns an upside-down table over."""
    z_up = Rotation.from_euler("x", 90, degrees=True).as_matrix()  # the table's +Y onto the file's +Z
    for suffix in ("obj", "stl", "ply"):
        standing = orientation.orient(_file(_turned(table(), z_up), tmp_path / f"z.{suffix}"))
        assert standing.changed and np.allclose(standing.up, [0, 0, 1]), standing.reason
        assert f"{suffix.upper()} states no up" in standing.reason and "Z-up" in standing.reason
        assert np.allclose(standing.front, [0, -1, 0]) and not standing.front_trusted
        np.testing.assert_allclose(standing.rotation @ standing.front, [0, 0, 1], atol=1e-9)  # faces +Z upright
        upright = orientation.orient(_file(table(), tmp_path / f"y.{suffix}"))
        assert not upright.changed and np.allclose(upright.front, [0, 0, 1]) and not upright.front_trusted
    flipped = orientation.orient(_file(_turned(table(), Rotation.from_euler("x", 180, degrees=True).as_matrix()),
                                       tmp_path / "flipped.obj"))
    assert not flipped.changed and "Y-up" in flipped.reason


def test_up_and_front_given_are_used_and_checked(tmp_path):
    mesh = _file(table(), tmp_path / "t.obj")
    given = orientation.orient(mesh, orientation.Axes("-x", "+y"))
    np.testing.assert_allclose(given.up, [-1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(given.rotation @ [-1, 0, 0], [0, 1, 0], atol=1e-9)
    assert given.front_trusted and np.allclose(given.front, [0, 1, 0]) and "as given" in given.front_reason
    with pytest.raises(ConfigError) as refused:
        orientation.orient(mesh, orientation.Axes("file", "-y"), role="source")
    assert refused.value.field == "source_front"
    with pytest.raises(ConfigError, match="right angles"):
        AlignConfig.from_preset("test", target_up="+z", target_front="-z")
    with pytest.raises(ConfigError):
        AlignConfig.from_preset("test", source_up="up")


def test_auto_front_faces_away_from_a_backrest():
    """A chair whose backrest is at -Z faces +Z; turned half a turn, -Z; both guesses, never trusted."""
    legs = [_box((0.05, 0.45, 0.05), (x, 0.225, z)) for x in (-0.2, 0.2) for z in (-0.2, 0.2)]
    chair = trimesh.util.concatenate([_box((0.45, 0.05, 0.45), (0, 0.47, 0)), _box((0.45, 0.5, 0.05), (0, 0.75, -0.2)),
                                      *legs])
    for turn, expected in ((0, [0, 0, 1]), (180, [0, 0, -1])):
        frame = orientation.orient(_turned(chair, Rotation.from_euler("y", turn, degrees=True).as_matrix()),
                                   orientation.Axes("file", "auto"))
        np.testing.assert_allclose(frame.front, expected, atol=1e-6)
        assert not frame.front_trusted and "auto" in frame.front_reason


def test_an_upside_down_table_in_an_obj_with_up_given_takes_the_cup_on_its_top(tmp_path):
    """The table is upside down in the OBJ on purpose (the rule keeps the file's +Y); ``target_up: -y`` says so,
    and "a cup on the table" ends on its top, which in the file frame is under the legs; the report says why."""
    from ctp_core import export

    flipped = _file(_turned(table(), Rotation.from_euler("x", 180, degrees=True).as_matrix()), tmp_path / "t.obj")
    cup = _file(_upright_y(trimesh.creation.cylinder(radius=0.08, height=0.2, sections=24)), tmp_path / "cup.obj")
    config = AlignConfig.from_preset("test", loss={"lambda_clip": 0.0}, target_up="-y", seed=1)
    result = stages.align(flipped, cup, "a cup on the table", config, target_name="table", source_name="cup")
    placed = trimesh.transform_points(cup.vertices, result.source_to_target)
    top = -0.75  # the table top's upper face, in the file frame (upside down: its top faces -y)
    assert result.relation["name"] == "on" and result.relation["holds"], result.relation
    assert placed[:, 1].max() <= top + 0.02 and placed[:, 1].min() > top - 0.3, placed[:, 1].min()
    assert np.abs(placed[:, [0, 2]].mean(0)).max() < 0.85  # over the top, not beside it
    frame = export.report(result)["extra"]["target_upright"]
    assert frame["up"] == [0, -1, 0] and frame["reason"] == "up: -y as given" and frame["changed"]
