"""``proximity``: exact closest points in bounded batches, and its per-mesh anchor tree."""

from __future__ import annotations

import gc

import numpy as np
import trimesh

from ctp_core.geometry import proximity


def _points(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-3, 3, (200, 3))


def test_matches_trimesh_in_small_batches():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    points = _points()
    expected_point, expected_distance, _ = trimesh.proximity.closest_point(mesh, points)
    found, distance, face = proximity.closest_points(mesh, points, batch=37)
    assert np.allclose(distance, expected_distance) and np.allclose(found, expected_point)
    assert np.allclose(trimesh.triangles.closest_point(mesh.triangles[face], points), found)
    assert np.isclose(proximity.min_distance(mesh, points, batch=37), expected_distance.min())


def test_points_over_several_bulk_queries_match_trimesh(monkeypatch):
    """The boxes of many points go to the R-tree a chunk at a time (``_CHUNK``): chunks and batches that end
    mid-way through a point's candidates give trimesh's answers still."""
    monkeypatch.setattr(proximity, "_CHUNK", 16)
    mesh = trimesh.creation.icosphere(subdivisions=2)
    points = _points(2)
    expected_point, expected_distance, _ = trimesh.proximity.closest_point(mesh, points)
    found, distance, _ = proximity.closest_points(mesh, points, batch=37)
    assert np.allclose(distance, expected_distance) and np.allclose(found, expected_point)


def test_anchor_tree_is_kept_per_mesh_until_it_changes():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    tree = proximity._anchors(mesh)
    assert proximity._anchors(mesh) is tree
    mesh.apply_translation((5.0, 0.0, 0.0))  # the cached anchors would now be off the surface
    moved = proximity._anchors(mesh)
    assert moved is not tree
    expected = trimesh.proximity.closest_point(mesh, _points(1))[1]
    assert np.allclose(proximity.closest_points(mesh, _points(1))[1], expected)
    key = id(mesh)
    del mesh
    gc.collect()
    assert key not in proximity._ANCHORS
