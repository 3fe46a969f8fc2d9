"""Metric correctness on arrangements with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from ctp_core import metrics


def _unwelded(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Same surface, every face with its own vertices: not watertight, so the winding estimate is used."""
    faces = np.arange(len(mesh.faces) * 3).reshape(-1, 3)
    return trimesh.Trimesh(mesh.triangles.reshape(-1, 3), faces, process=False)


def _moved(mesh: trimesh.Trimesh, offset) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_translation(offset)
    return out


def _pose(rotation=None, translation=(0, 0, 0), scale=1.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = scale * (np.eye(3) if rotation is None else np.asarray(rotation))
    m[:3, 3] = translation
    return m


@pytest.fixture(scope="module")
def points() -> np.ndarray:
    box = trimesh.creation.box((0.4, 1.0, 0.2))  # asymmetric, so every rotation is visible
    return trimesh.sample.sample_surface(box, 1500, seed=3)[0]


@pytest.mark.parametrize("closed", [True, False], ids=["exact", "winding"])
@pytest.mark.parametrize(("offset", "expected"), [((2.0, 0, 0), 0.0), ((0, 0, 0), 1.0), ((0.5, 0, 0), 1 / 3)],
                         ids=["disjoint", "identical", "half-overlap"])
def test_iou_of_boxes(closed, offset, expected):
    a, b = trimesh.creation.box(), _moved(trimesh.creation.box(), offset)
    if not closed:
        a, b = _unwelded(a), _unwelded(b)
    result = metrics.intersection_over_union(a, b)
    assert result.method == ("exact" if closed else "winding")
    assert result.iou == pytest.approx(expected, abs=1e-6 if closed else 0.02)


def test_iou_estimate_of_overlapping_spheres_matches_exact():
    a, b = trimesh.creation.icosphere(), _moved(trimesh.creation.icosphere(), (0.7, 0.2, 0))
    exact = metrics.intersection_over_union(a, b)
    estimate = metrics.intersection_over_union(_unwelded(a), _unwelded(b))
    assert exact.method == "exact" and estimate.method == "winding"
    assert 0.1 < exact.iou < 0.5
    assert estimate.iou == pytest.approx(exact.iou, rel=0.05)


def test_winding_numbers_count_overlapping_parts():
    a = trimesh.creation.icosphere()
    both = trimesh.util.concatenate([a, _moved(a, (1.0, 0, 0))])
    w = metrics.winding_numbers(both, np.array([[-0.5, 0, 0], [0.5, 0, 0], [3.0, 0, 0], [0, 0.99, 0]]))
    assert w == pytest.approx([1.0, 2.0, 0.0, 1.0], abs=1e-6)


def test_winding_number_of_an_open_mesh_is_fractional():
    """A box without its top face: a point inside sees the hole in some directions, so 0 < w < 1."""
    box = trimesh.creation.box()
    top = box.face_normals[:, 2] > 0.5
    open_box = trimesh.Trimesh(box.vertices, box.faces[~top])
    w = metrics.winding_numbers(open_box, np.array([[0, 0, 0.4], [0, 0, -0.4]]))
    assert 0.0 < w[0] < w[1] < 1.0


def test_contact_distance_is_the_gap_over_target_size():
    target = trimesh.creation.box((2.0, 1.0, 1.0))
    apart = _moved(trimesh.creation.box((0.5, 0.5, 0.5)), (1.0 + 0.25 + 0.3, 0, 0))  # gap 0.3
    touching = _moved(trimesh.creation.box((0.5, 0.5, 0.5)), (1.25, 0, 0))
    assert metrics.contact_distance(target, apart) == pytest.approx(0.3 / 2.0, rel=1e-6)
    assert metrics.contact_distance(target, touching) == pytest.approx(0.0, abs=1e-9)


def test_identity_pose_has_no_error(points):
    ref = _pose(trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])[:3, :3], (1, -2, 0.5), 2.0)
    errors = metrics.pose_errors(points, ref, ref)
    assert errors["adds"] == pytest.approx(0.0, abs=1e-12)
    assert errors["translation_error"] == pytest.approx(0.0, abs=1e-12)
    assert errors["rotation_error_deg"] == pytest.approx(0.0, abs=1e-4)
    assert errors["scale_error"] == pytest.approx(0.0, abs=1e-12)
    assert errors["success"] is True


def test_pose_errors_of_known_offsets(points):
    ref = _pose(translation=(0, 0, 0), scale=2.0)
    diagonal = 2.0 * np.linalg.norm([0.4, 1.0, 0.2])
    moved = metrics.pose_errors(points, _pose(translation=(0.3, 0, 0), scale=2.0), ref)
    assert moved["translation_error"] == pytest.approx(0.3 / diagonal)
    assert 0 < moved["adds"] <= 0.3 / diagonal + 1e-9  # nearest points: never more than the shift
    turned = metrics.pose_errors(points, _pose(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1])[:3, :3],
                                               scale=2.0), ref)
    assert turned["rotation_error_deg"] == pytest.approx(90.0)
    assert turned["adds"] > metrics.SUCCESS_ADDS and turned["success"] is False
    grown = metrics.pose_errors(points, _pose(scale=4.0), ref)
    assert grown["scale_error"] == pytest.approx(np.log(2.0))


def test_adds_forgives_symmetry():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    pts = trimesh.sample.sample_surface(sphere, 2000, seed=0)[0]
    turn = _pose(trimesh.transformations.rotation_matrix(1.2, [0.3, 1, 0.2])[:3, :3])
    errors = metrics.pose_errors(pts, turn, np.eye(4))
    assert errors["rotation_error_deg"] > 60
    assert errors["adds"] < 0.02 and errors["success"] is True
