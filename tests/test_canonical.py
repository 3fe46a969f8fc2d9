"""Auto-Align: authored-upright uploads stay as they are; tilted, lying and upside-down ones stand up."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial.transform import Rotation

from ctp_core.guide.upright import upright_judge
from ctp_core.orientation import canonical


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


class _TopRedGuide:
    """A stand-in guide that likes renders whose upper half is red and lower half is not.

    Through ``upright.upright_judge`` it proves that each candidate is rendered the right way up: a
    candidate turned the wrong way (R instead of R.T, or a camera upside down) would win otherwise.
    """

    def encode_text(self, texts: list[str]) -> torch.Tensor:
        return torch.ones(len(texts), 1)

    def score(self, images: torch.Tensor, text: torch.Tensor) -> torch.Tensor:
        red = images[:, 0] - images[:, 1:].mean(1)  # (N, H, W)
        half = images.shape[-2] // 2
        return red[:, :half].mean((1, 2)) - red[:, half:].mean((1, 2))


def _red_topped_cube() -> trimesh.Trimesh:
    """A cube, authored with its red face up: geometry alone cannot tell which face that is."""
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    cube.unmerge_vertices()
    colours = np.tile(np.array([120, 120, 120, 255], np.uint8), (len(cube.faces), 1))
    colours[cube.face_normals[:, 1] > 0.9] = [220, 20, 20, 255]
    cube.visual.face_colors = colours
    return cube


def test_judge_finds_the_up_geometry_cannot():
    cube = _red_topped_cube()
    judge = lambda mesh: upright_judge(mesh, _TopRedGuide(), "cube", image_size=64)  # noqa: E731
    kept = canonical.upright_rotation(cube, judge=judge(cube))
    assert not kept.changed and np.array_equal(kept.rotation, np.eye(3))
    assert kept.reason.startswith("judged")
    for rotation in Rotation.random(4, random_state=5).as_matrix():
        turned = _turned(cube, rotation)
        result = canonical.upright_rotation(turned, judge=judge(turned))
        assert result.changed
        assert _angle_to_file_y(rotation, result) < 1.0  # the red face, snapped to the cube's axis
        assert result.candidates[0]["judge_score"] >= result.candidates[-1]["judge_score"]


def test_an_undecided_judge_keeps_the_file_up():
    lamp = _turned(_lamp(), Rotation.from_euler("x", 90, degrees=True).as_matrix())  # lying: geometry would turn it
    assert canonical.upright_rotation(lamp).changed
    flat = canonical.upright_rotation(lamp, judge=lambda rotations: np.zeros(len(rotations)))
    assert not flat.changed and np.array_equal(flat.rotation, np.eye(3))
    # a judge preferring the second candidate by less than the margin changes nothing either
    slight = canonical.upright_rotation(lamp, judge=lambda r: np.r_[0.0, 0.005, np.zeros(len(r) - 2)])
    assert not slight.changed
