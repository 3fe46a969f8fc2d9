"""Surface samples: exact count, on the surface, deterministic, and spread over a low-poly mesh."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from ctp_core.geometry.sampling import surface_samples


def _star(points: int = 5) -> trimesh.Trimesh:
    """A flat 5-point star extruded thin: 20 faces, like the benchmark's low-poly star (top + bottom fans)."""
    angles = np.arange(2 * points) * np.pi / points
    radii = np.where(np.arange(2 * points) % 2 == 0, 1.0, 0.4)
    rim = np.c_[radii * np.cos(angles), radii * np.sin(angles), np.zeros(2 * points)]
    vertices = np.vstack([[0, 0, 0.1], [0, 0, -0.1], rim])
    ring = np.arange(2 * points) + 2
    nxt = np.roll(ring, -1)
    faces = np.vstack([np.c_[np.zeros_like(ring), ring, nxt], np.c_[np.ones_like(ring), nxt, ring]])
    return trimesh.Trimesh(vertices, faces, process=False)


def test_count_surface_and_normals():
    mesh = _star()
    assert len(mesh.faces) == 20
    points, normals = surface_samples(mesh, 3000, seed=0)
    assert points.shape == (3000, 3) and normals.shape == (3000, 3)
    _, distance, face = trimesh.proximity.closest_point(mesh, points)
    assert distance.max() < 1e-9
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    # each normal is the normal of the face its point lies on (up to numerically shared edges)
    assert (np.einsum("ij,ij->i", normals, mesh.face_normals[face]) > 0.999).mean() > 0.99


def test_deterministic_by_seed():
    mesh = _star()
    a = surface_samples(mesh, 500, seed=7)
    b = surface_samples(mesh, 500, seed=7)
    c = surface_samples(mesh, 500, seed=8)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.allclose(a[0], c[0])


def test_every_face_gets_its_share():
    mesh = _star()
    count = 1000
    points, _ = surface_samples(mesh, count, seed=1)
    _, _, face = trimesh.proximity.closest_point(mesh, points)
    hits = np.bincount(face, minlength=len(mesh.faces))
    expected = count * mesh.area_faces / mesh.area
    assert (hits >= np.floor(expected) - 1).all() and (hits <= np.ceil(expected) + 1).all()


def test_spread_beats_independent_sampling():
    """Holes (99th percentile distance from a dense reference to the nearest sample) are smaller than
    with i.i.d. area-weighted sampling of the same count, averaged over seeds."""
    mesh = _star()
    reference, _ = trimesh.sample.sample_surface(mesh, 50_000, seed=123)
    ratios = []
    for seed in range(3):
        ours, _ = surface_samples(mesh, 400, seed=seed)
        iid, _ = trimesh.sample.sample_surface(mesh, 400, seed=seed)
        holes = [np.percentile(cKDTree(p).query(reference)[0], 99) for p in (ours, iid)]
        ratios.append(holes[0] / holes[1])
    assert np.mean(ratios) < 0.9


def test_refuses_degenerate_input():
    flat = trimesh.Trimesh(np.zeros((3, 3)), [[0, 1, 2]], process=False)
    with pytest.raises(ValueError):
        surface_samples(flat, 10, seed=0)
    with pytest.raises(ValueError):
        surface_samples(_star(), 0, seed=0)
