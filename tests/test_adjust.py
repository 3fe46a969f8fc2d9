"""The engine's side of adjusting a result by hand (``ctp_core.adjust``): a client's matrix checked, "drop" along
the job's up (not the file's +Y), a result GLB read back into its target and source, and the saved report."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from ctp_core.adjust import adjust, read_back
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.export import adjusted_report, arrangement_glb, transform
from ctp_core.geometry import frames
from ctp_core.io import load_objects

CONFIG = AlignConfig.from_preset("test", model="random:tiny", seed=3)
BALL = trimesh.creation.icosphere(subdivisions=2, radius=0.15)


def at(x=0.0, y=0.0, z=0.0, turn: np.ndarray | None = None, scale=1.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = scale * (np.eye(3) if turn is None else turn)
    m[:3, 3] = [x, y, z]
    return m


def test_a_clients_matrix_is_checked_and_snapped_to_a_similarity():
    turn = trimesh.transformations.rotation_matrix(0.7, [1, 2, 3])[:3, :3]
    rounded = np.round(at(0.1, 0.2, 0.3, turn, 2.0), 6)  # as JSON from a browser might carry it
    similarity = frames.checked_similarity(rounded.tolist(), frames.SOURCE_FILE, frames.TARGET_FILE)
    assert np.allclose(similarity.matrix, rounded, atol=1e-5) and math.isclose(similarity.scale, 2.0, rel_tol=1e-6)
    assert np.allclose(similarity.rotation @ similarity.rotation.T, np.eye(3), atol=1e-12)  # exactly a rotation
    uneven, sheared, last_row = at(scale=1.0), at(), at()
    uneven[0, 0] = 2.0
    sheared[0, 1] = 0.3
    last_row[3, 0] = 1.0
    bad = {"shape": np.eye(3), "ragged": [[1, 0], [0]], "nan": at(x=math.nan), "mirror": np.diag([-1.0, 1, 1, 1]),
           "flat": np.diag([1.0, 0, 1, 1]), "uneven": uneven, "sheared": sheared, "last row": last_row}
    for name, matrix in bad.items():
        with pytest.raises(ValueError):
            frames.checked_similarity(matrix, frames.SOURCE_FILE, frames.TARGET_FILE)
        with pytest.raises(ConfigError) as refused:
            adjust(trimesh.creation.box(), BALL, matrix, CONFIG)
        assert refused.value.code == "invalid_transform", name
    assert np.allclose(frames.checked_direction([0, 0, 3]), [0, 0, 1])
    for direction in ([0, 0, 0], [1, 2], [math.inf, 0, 0], None):
        with pytest.raises(ValueError):
            frames.checked_direction(direction)


def test_drop_falls_along_the_jobs_up_not_the_files_y():
    """A slab lying in its file with +Z up (the job turned it upright: file +Z -> +Y): a ball above it along +Z
    drops onto it along -Z; its x and y stay."""
    slab = trimesh.creation.box((1.0, 0.8, 0.1))  # its top face at z = 0.05
    upright = trimesh.transformations.rotation_matrix(-math.pi / 2, [1, 0, 0])[:3, :3]  # file +Z -> upright +Y
    assert np.allclose(upright @ [0, 0, 1], [0, 1, 0])
    dropped = adjust(slab, BALL, at(0.1, 0.2, 0.8), CONFIG, settle="drop", upright=upright)
    x, y, z = dropped.source_to_target[:3, 3]
    assert dropped.settled and not dropped.on_floor and dropped.touching, dropped
    assert (x, y) == pytest.approx((0.1, 0.2), abs=1e-6) and z == pytest.approx(0.2, abs=0.01)
    assert dropped.moved == pytest.approx(0.6 / np.linalg.norm(BALL.extents), rel=0.05)
    pushed = adjust(slab, BALL, at(0.1, 0.2, 0.8), CONFIG, settle="push", direction=[0, 0, -5], upright=upright)
    assert np.allclose(pushed.source_to_target, dropped.source_to_target, atol=1e-5)  # the same move, asked for
    with pytest.raises(ConfigError) as refused:
        adjust(slab, BALL, at(), CONFIG, settle="push")
    assert refused.value.code == "invalid_direction"


def test_a_result_glb_reads_back_as_it_was_written_and_the_report_keeps_the_first_original():
    table = trimesh.creation.box((1.0, 0.1, 0.8))
    placed = at(0.1, 0.35, 0.0, trimesh.transformations.rotation_matrix(0.5, [0, 1, 0])[:3, :3], 1.5)
    scene = load_objects(arrangement_glb(table, BALL, placed, "ball", "table"), filename="result.glb")
    target, source, name = read_back(scene, placed)
    assert name == "ball" and isinstance(target, trimesh.Trimesh)
    again = load_objects(arrangement_glb(target, source, placed, name), filename="result.glb")
    assert list(again.geometry) == ["table", "ball"]  # saved again under the same names
    assert np.allclose(source.bounds, BALL.bounds, atol=1e-5) and np.allclose(target.bounds, table.bounds)
    done = adjust(target, source, placed, CONFIG, settle="drop")  # upright None: found from the table as a run does
    assert done.settled and done.touching and done.penetration < 0.01, done
    original = {"transform": transform(frames.Similarity(placed, frames.SOURCE_FILE, frames.TARGET_FILE)),
                "prompt": "a ball on a table"}
    first = adjusted_report(original, done, at="2026-12-03T10:00:00+00:00")
    assert first["adjusted"] is True and first["prompt"] == "a ball on a table"
    assert np.allclose(first["transform"]["matrix"], done.source_to_target)
    assert first["adjustment"]["original_transform"] == original["transform"]
    assert first["adjustment"]["settle"] == "drop"
    second = adjusted_report(first, done, at="2026-12-03T10:05:00+00:00")
    assert second["adjustment"]["original_transform"] == original["transform"]  # the run's, through later saves
    with pytest.raises(ConfigError):
        read_back(load_objects(table.export(file_type="glb"), filename="t.glb"), placed)
