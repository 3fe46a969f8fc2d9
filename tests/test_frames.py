"""Frames: similarities compose only along matching frames, invert exactly, and normalise as documented."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ctp_core.geometry import frames
from ctp_core.geometry.frames import Similarity


def _random_similarity(rng: np.random.Generator, from_frame: str, to_frame: str) -> Similarity:
    rotation = Rotation.random(random_state=rng).as_matrix()
    return Similarity.from_parts(rotation, rng.normal(size=3) * 5, rng.uniform(0.1, 10), from_frame, to_frame)


def test_inverse_round_trip_and_parts():
    rng = np.random.default_rng(0)
    a = _random_similarity(rng, "a", "b")
    points = rng.normal(size=(50, 3))
    back = a.inverse().apply(a.apply(points))
    assert np.allclose(back, points, atol=1e-9)
    assert (a.inverse().from_frame, a.inverse().to_frame) == ("b", "a")
    assert np.allclose((a.inverse() @ a).matrix, np.eye(4), atol=1e-9)
    assert np.allclose(a.rotation @ a.rotation.T, np.eye(3), atol=1e-9)
    assert np.isclose(a.inverse().scale, 1 / a.scale)
    assert np.allclose(a.translation, a.apply(np.zeros((1, 3)))[0])


def test_directions_rotate_without_scale_or_shift():
    rng = np.random.default_rng(4)
    a = _random_similarity(rng, "a", "b")
    normals = rng.normal(size=(30, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    turned = a.apply_directions(normals)
    assert np.allclose(np.linalg.norm(turned, axis=1), 1.0)
    assert np.allclose(turned, (a.apply(normals) - a.translation) / a.scale)


def test_composition_applies_right_first_and_checks_frames():
    rng = np.random.default_rng(1)
    a, b = _random_similarity(rng, "a", "b"), _random_similarity(rng, "b", "c")
    points = rng.normal(size=(20, 3))
    chained = b @ a
    assert (chained.from_frame, chained.to_frame) == ("a", "c")
    assert np.allclose(chained.apply(points), b.apply(a.apply(points)))
    with pytest.raises(ValueError, match="frames do not chain"):
        _ = a @ b


def test_matrix_is_frozen_and_validated():
    matrix = np.eye(4)
    s = Similarity(matrix, "a", "b")
    matrix[0, 3] = 7.0  # the caller's array is not aliased
    assert s.matrix[0, 3] == 0.0
    with pytest.raises(ValueError):
        s.matrix[0, 0] = 2.0
    with pytest.raises(ValueError):
        Similarity(np.eye(3), "a", "b")
    with pytest.raises(ValueError):
        Similarity(np.full((4, 4), np.nan), "a", "b")


def test_normalisation_centres_target_and_source_keeps_relative_size():
    lo, hi = np.array([1.0, 2.0, 3.0]), np.array([5.0, 3.0, 4.0])  # longest side 4 along x
    norm = frames.normalisation(np.array([lo, hi]), from_frame=frames.TARGET_FILE)
    out = norm.apply(np.array([lo, hi]))
    assert np.allclose(out.mean(0), 0.0)
    assert np.isclose((out[1] - out[0]).max(), 2.0)
    assert norm.to_frame == frames.NORMALISED

    source_lo, source_hi = np.array([10.0, 10.0, 10.0]), np.array([12.0, 11.0, 10.5])
    local = frames.source_local(np.array([source_lo, source_hi]), norm)
    placed = local.apply(np.array([source_lo, source_hi]))
    assert np.allclose(placed.mean(0), 0.0)
    # the source's size relative to the target survives: 2 / 4 of the target's longest side
    assert np.isclose((placed[1] - placed[0]).max(), 2.0 * 2.0 / 4.0)
    assert (local.from_frame, local.to_frame) == (frames.SOURCE_FILE, frames.SOURCE_LOCAL)
    with pytest.raises(ValueError):
        frames.normalisation(np.array([lo, lo]))


def test_target_to_normalised_is_tight_in_the_upright_frame():
    rng = np.random.default_rng(2)
    box = rng.uniform(-1, 1, size=(200, 3)) * [3.0, 1.0, 0.5]
    upright = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    t2n = frames.target_to_normalised(box, upright)
    assert (t2n.from_frame, t2n.to_frame) == (frames.TARGET_FILE, frames.NORMALISED)
    out = t2n.apply(box)
    extent = out.max(0) - out.min(0)
    assert np.isclose(extent.max(), 2.0) and np.allclose((out.max(0) + out.min(0)) / 2, 0.0)
    # the rotation part is the upright rotation
    assert np.allclose(t2n.rotation, upright)


def test_source_to_target_undoes_the_frames():
    rng = np.random.default_rng(3)
    target = rng.normal(size=(100, 3)) * 4 + 10
    source = rng.normal(size=(100, 3)) + [0, 50, 0]
    upright = Rotation.random(random_state=rng).as_matrix()
    t2n = frames.target_to_normalised(target, upright)
    s2l = frames.source_local(np.array([source.min(0), source.max(0)]), t2n)
    pose = _random_similarity(rng, frames.SOURCE_LOCAL, frames.NORMALISED)
    answer = frames.source_to_target(pose.matrix, t2n, s2l)
    assert (answer.from_frame, answer.to_frame) == (frames.SOURCE_FILE, frames.TARGET_FILE)
    # placing the source with the answer, then normalising, equals posing its local copy
    assert np.allclose(t2n.apply(answer.apply(source)), pose.apply(s2l.apply(source)), atol=1e-9)
    assert np.isclose(answer.scale, pose.scale)


def test_z_up_writes_a_gltf_transform_in_blenders_axes():
    """Up in glTF (+Y) is up in Blender (+Z), glTF's +Z (towards the viewer) is Blender's -Y; a turn about the
    vertical stays one about the vertical, by the same angle."""
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("y", 30, degrees=True).as_matrix()
    turn[:3, 3] = [0.1, 0.75, 0.2]
    blender = frames.z_up(turn)
    assert np.allclose(blender[:3, 3], [0.1, -0.2, 0.75])
    assert np.allclose(blender[:3, :3], Rotation.from_euler("z", 30, degrees=True).as_matrix())
    point = np.array([0.3, 0.4, 0.5, 1.0])  # the same point in both axes: glTF (x, y, z) is Blender (x, -z, y)
    as_blender = lambda p: np.array([p[0], -p[2], p[1], 1.0])  # noqa: E731
    assert np.allclose(blender @ as_blender(point), as_blender(turn @ point))
