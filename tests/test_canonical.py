"""Auto-Align: authored-upright uploads stay as they are; tilted, lying and upside-down ones stand up."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from ctp_core import canonical


def _turned(mesh: trimesh.Trimesh, rotation: np.ndarray) -> trimesh.Trimesh:
    out = mesh.copy()
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    out.apply_transform(matrix)
    return out


def _lamp() -> trimesh.Trimesh:
    """A table lamp authored +Y up: heavy flat foot, thin pole, conical shade."""
    base = trimesh.creation.cylinder(radius=0.5, height=0.1, sections=48).apply_translation([0, 0, 0.05])
    pole = trimesh.creation.cylinder(radius=0.05, height=1.2, sections=16).apply_translation([0, 0, 0.7])
    shade = trimesh.creation.cone(radius=0.35, height=0.4, sections=48).apply_translation([0, 0, 1.2])
    lamp = trimesh.util.concatenate([base, pole, shade])
    return lamp.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))


def _chair() -> trimesh.Trimesh:
    parts = [trimesh.creation.box(extents=(1, 0.1, 1)).apply_translation([0, 0.5, 0]),
             trimesh.creation.box(extents=(1, 0.8, 0.1)).apply_translation([0, 0.95, -0.45])]
    parts += [trimesh.creation.box(extents=(0.1, 0.5, 0.1)).apply_translation([x, 0.25, z])
              for x in (-0.45, 0.45) for z in (-0.45, 0.45)]
    return trimesh.util.concatenate(parts)


def _angle_to_file_y(mesh_rotation: np.ndarray, upright: canonical.Upright) -> float:
    """Degrees between the recovered up (taken back to the authored frame) and the authored +Y."""
    up = mesh_rotation.T @ upright.up
    return float(np.degrees(np.arccos(np.clip(up[1], -1.0, 1.0))))


@pytest.mark.parametrize("make", [_lamp, _chair, lambda: trimesh.creation.box(extents=(2.0, 1.0, 0.5))])
def test_authored_upright_is_kept(make):
    result = canonical.upright_rotation(make())
    assert not result.changed
    assert np.array_equal(result.rotation, np.eye(3))
    assert result.reason


def test_tilted_lamp_is_stood_up():
    lamp = _lamp()
    for rotation in Rotation.random(6, random_state=3).as_matrix():
        result = canonical.upright_rotation(_turned(lamp, rotation))
        assert result.changed
        assert np.allclose(result.rotation @ result.rotation.T, np.eye(3), atol=1e-9)
        assert np.isclose(np.linalg.det(result.rotation), 1.0)
        assert _angle_to_file_y(rotation, result) < 10.0
        # the upright frame really has the foot at the bottom: most area sits low
        heights = _turned(_turned(lamp, rotation), result.rotation).vertices[:, 1]
        assert np.median(heights) < (heights.min() + heights.max()) / 2


@pytest.mark.parametrize("degrees", [90.0, 180.0])
def test_lying_and_upside_down_lamp(degrees):
    rotation = Rotation.from_euler("x", degrees, degrees=True).as_matrix()
    result = canonical.upright_rotation(_turned(_lamp(), rotation))
    assert result.changed
    assert _angle_to_file_y(rotation, result) < 1.0  # snapped to the dominant axis


def test_box_axes_and_square_yaw():
    """A rotated box: its dominant axes are found to <1°, and the upright frame is square to X/Z."""
    rotation = Rotation.from_euler("xyz", [20, 35, -50], degrees=True).as_matrix()
    box = _turned(trimesh.creation.box(extents=(2.0, 1.0, 0.5)), rotation)
    axes = canonical.dominant_axes(box, seed=0)
    cosines = np.abs(axes @ rotation).max(axis=1)  # each found axis against the box's own axes
    assert (cosines > np.cos(np.radians(1.0))).all()
    result = canonical.upright_rotation(box)
    upright = _turned(box, result.rotation)
    assert np.allclose(np.sort(upright.extents), [0.5, 1.0, 2.0], atol=1e-6)  # axis-aligned again


def test_deterministic_and_no_base_means_no_change():
    lamp = _turned(_lamp(), Rotation.random(random_state=9).as_matrix())
    a, b = canonical.upright_rotation(lamp, seed=4), canonical.upright_rotation(lamp, seed=4)
    assert np.array_equal(a.rotation, b.rotation)
    sphere = _turned(trimesh.creation.icosphere(subdivisions=3), Rotation.random(random_state=1).as_matrix())
    result = canonical.upright_rotation(sphere)
    assert not result.changed and "no flat base" in result.reason
    assert not canonical.identity().changed
