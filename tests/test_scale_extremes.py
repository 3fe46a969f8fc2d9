"""Any units, any size ratio (issue 25): the engine's cost does not grow with the size ratio or the absolute
scale, its answers do not depend on the units, and a ratio beyond what the method does well ends with a
``scale_ratio_extreme`` warning in the report (docs/engine.md, "Any units, any size ratio")."""

from __future__ import annotations

import io as bytes_io
import json
import math
import os
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from ctp_core import io
from ctp_core.align import SIZE_RATIO_RANGE, align, scale_ratio_warning
from ctp_core.config import AlignConfig
from ctp_core.export import report
from ctp_core.geometry import sampling
from ctp_core.geometry.pose import quaternion_to_matrix
from ctp_core.guide.loaders import get_guide
from ctp_core.orientation import canonical
from ctp_core.pairs import prepare_pair
from ctp_core.search import proposals

REPO = Path(__file__).resolve().parents[1]
PROPERTY = settings(max_examples=8, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def _dense_summits(points: np.ndarray, radius: float) -> np.ndarray:
    """The former dense-grid ``summits`` (a height grid of ``radius`` cells over x, z; its memory grows with the
    extent over the radius squared): the reference the sparse one must equal."""
    cells = np.floor(points[:, [0, 2]] / max(radius, 1e-9)).astype(np.int64)
    cells -= cells.min(0)
    shape = cells.max(0) + 3
    height = np.full(shape, -np.inf)
    np.maximum.at(height, (cells[:, 0] + 1, cells[:, 1] + 1), points[:, 1])
    around = np.max([np.roll(np.roll(height, i, 0), j, 1) for i in (-1, 0, 1) for j in (-1, 0, 1)], axis=0)
    top = height[cells[:, 0] + 1, cells[:, 1] + 1]
    peaks = np.flatnonzero((points[:, 1] >= top) & (top >= around[cells[:, 0] + 1, cells[:, 1] + 1]))
    return peaks[np.argsort(-points[peaks, 1], kind="stable")]


def test_sparse_summits_equal_the_dense_grid_on_random_inputs():
    rng = np.random.default_rng(25)
    for trial in range(60):
        n = int(rng.integers(1, 3000))
        points = rng.normal(size=(n, 3)) * rng.uniform(0.01, 3.0, size=3) + rng.uniform(-2, 2, size=3)
        if trial % 3 == 0:  # ties: heights and columns on a lattice, so several samples share a cell's top
            points = np.round(points * 4) / 4
        radius = float(rng.choice([1e-3, 0.01, 0.05, 0.2, 1.0, 10.0]))
        radius *= float(np.ptp(points[:, [0, 2]], axis=0).max()) if trial % 2 else 1.0
        if np.ptp(points[:, [0, 2]], axis=0).max() / radius > 3000:  # the dense grid would be too large here
            radius = float(np.ptp(points[:, [0, 2]], axis=0).max()) / 3000
        np.testing.assert_array_equal(sampling.summits(points, radius), _dense_summits(points, radius))
    assert len(sampling.summits(np.zeros((0, 3)), 0.1)) == 0


def test_summits_stay_small_for_any_radius():
    """A radius 1e-7 over a 1-unit spread was a 1e7 x 1e7 dense grid (800 TB); now milliseconds and O(N)."""
    points = np.random.default_rng(0).random((5000, 3))
    tracemalloc.start()
    began = time.perf_counter()
    peaks = sampling.summits(points, 1e-7)
    seconds = time.perf_counter() - began
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert seconds < 2.0 and peak < 20 * 2**20, (seconds, peak)
    assert len(peaks) == len(points)  # every sample alone in its column: each is its own summit
    assert points[peaks[0], 1] == points[:, 1].max()


def _scaled(mesh: trimesh.Trimesh, factor: float) -> trimesh.Trimesh:
    return trimesh.Trimesh(np.asarray(mesh.vertices) * factor, mesh.faces, process=False)


@pytest.mark.parametrize("shape", ["box", "cylinder", "sphere"])
def test_source_orientations_do_not_depend_on_units(shape):
    """At 1e-6 trimesh's convex hull of the source had no faces: no resting poses, fewer orientations. Now the
    orientations at 1e-6 are those at 1, and at 1e6 the same resting poses (equally probable ones, a cylinder
    on either end, may come in another order at any scale: the rounding of a scaled copy breaks their tie; seen
    at 1e-6 with trimesh 5.2)."""
    source = {"box": trimesh.creation.box(extents=[0.3, 0.2, 0.1]),
              "cylinder": trimesh.creation.cylinder(radius=0.1, height=0.3, sections=32),
              "sphere": trimesh.creation.icosphere(subdivisions=3, radius=0.15)}[shape]
    target = trimesh.creation.box(extents=[1.0, 0.2, 1.0])
    config = AlignConfig.from_preset("test", model="random:tiny")
    found, rests = [], []
    for factor in (1.0, 1e-6, 1e6):
        pair = prepare_pair(_scaled(target, factor), _scaled(source, factor), samples=200, seed=0)
        found.append(proposals.orientations(pair, config, torch.Generator().manual_seed(0)))
        poses = proposals._stable_poses(canonical.unit_size(pair.source), 0)
        rests.append(sorted(tuple(np.round(np.asarray(m)[:3, :3], 4).ravel() + 0.0) for m in poses))
    assert len(rests[0]) > 0 and rests[1] == rests[0] and rests[2] == rests[0]
    # the same set of source poses up to the source's own symmetry (tied resting poses may swap places, and a
    # cylinder on its side turned +90 or -90 degrees is one pose): the turned source's extents, sorted
    assert _extents(source, found[1]) == _extents(source, found[0])
    assert found[2].shape == found[0].shape


def _extents(mesh: trimesh.Trimesh, q: torch.Tensor) -> list[tuple[float, ...]]:
    """The axis-aligned extents of ``mesh`` turned by each unit quaternion, rounded and sorted."""
    turned = torch.einsum("bij,nj->bni", quaternion_to_matrix(q.double()), torch.as_tensor(mesh.vertices))
    extents = (turned.amax(dim=1) - turned.amin(dim=1)).numpy()
    return sorted(tuple(np.round(row, 4) + 0.0) for row in extents)


def test_tiny_meshes_keep_their_vertices_when_loaded():
    """trimesh merges vertices at an absolute 1e-8: a 0.3 µm sphere kept 26 of its 642 vertices."""
    for factor in (1.0, 1e-7, 1e-9):
        sphere = _scaled(trimesh.creation.icosphere(subdivisions=3, radius=0.15), factor)
        loaded = io.load_mesh(sphere.export(file_type="ply"), filename="sphere.ply")
        assert len(loaded.vertices) == 642 and len(loaded.faces) == 1280
    assert io.merge_digits(1.0) == io.merge_digits(0.01) == io.merge_digits(1e6) == 8  # ordinary sizes: as before
    assert io.merge_digits(3e-7) == 13


def test_scale_ratio_warning_range():
    low, high = SIZE_RATIO_RANGE
    assert scale_ratio_warning(1.0) is None and scale_ratio_warning(low) is None and scale_ratio_warning(high) is None
    for ratio in (low / 2, high * 2, 3e-5):
        warning = scale_ratio_warning(ratio)
        assert warning["code"] == "scale_ratio_extreme" and warning["size_ratio"] == ratio
        assert "\n" not in warning["message"] and f"{ratio:.3g}" in warning["message"]


# --- align end to end (preset test, random:tiny): it ends, the answer is finite and near the target ---------


@pytest.fixture(scope="module")
def guide():
    return get_guide("random:tiny")


def _shape(name: str) -> trimesh.Trimesh:
    if name == "box":
        return trimesh.creation.box(extents=[0.3, 0.3, 0.3])
    if name == "sphere":
        return trimesh.creation.icosphere(subdivisions=2, radius=0.15)
    if name == "needle":
        return trimesh.creation.box(extents=[0.001, 0.001, 1.0])
    if name == "pancake":
        return trimesh.creation.box(extents=[1.0, 0.001, 1.0])
    if name == "triangle":
        return trimesh.Trimesh([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]], [[0, 1, 2]], process=False)
    if name == "scatter":  # 200 triangles of about 1e-4 spread over a metre cube
        rng = np.random.default_rng(0)
        vertices = np.concatenate([rng.random(3) + rng.normal(size=(3, 3)) * 1e-4 for _ in range(200)])
        return trimesh.Trimesh(vertices, np.arange(len(vertices)).reshape(-1, 3), process=False)
    raise ValueError(name)


def _loaded(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Through the loader's checks (vertex merging included), as an upload would be."""
    buffer = bytes_io.BytesIO()
    mesh.export(buffer, file_type="ply")
    return io.load_mesh(buffer.getvalue(), filename="mesh.ply")


def _diagonal(mesh: trimesh.Trimesh | np.ndarray) -> float:
    vertices = mesh if isinstance(mesh, np.ndarray) else np.asarray(mesh.vertices)
    return float(np.linalg.norm(np.ptp(vertices, axis=0)))


def _aligned(target: trimesh.Trimesh, source: trimesh.Trimesh, guide, guided: bool = True) -> dict:
    config = AlignConfig.from_preset("test", model="random:tiny", threads=2,
                                     **({} if guided else {"loss": {"lambda_clip": 0.0}}))
    result = align(target, source, "a box on a sphere", config, guide=guide if guided else None)
    matrix = np.asarray(result.source_to_target)
    assert np.isfinite(matrix).all() and math.isfinite(result.objective)
    placed = trimesh.transform_points(np.asarray(source.vertices), matrix)
    lo, hi = np.asarray(target.vertices).min(0), np.asarray(target.vertices).max(0)
    gap = np.linalg.norm(np.maximum(0.0, np.maximum(lo - placed.max(0), placed.min(0) - hi)))
    # the source ends near the target: within 3 diagonals of the larger of the two (a source many times the
    # target may end a few of its own radii away: its approach samples are sparser than the target is wide,
    # docs/engine.md "Any units, any size ratio")
    assert gap <= 3 * max(_diagonal(target), _diagonal(placed)), (gap, _diagonal(target), _diagonal(placed))
    data = json.loads(json.dumps(report(result)))  # JSON as written
    assert data["warnings"] == result.warnings
    return data


def _expect_warning(ratio: float) -> bool:
    low, high = SIZE_RATIO_RANGE
    return not low <= ratio <= high


def _codes(data: dict) -> list[str]:
    return [w["code"] for w in data["warnings"]]


@PROPERTY
@given(exponent=st.floats(-4.0, 4.0), source_is_box=st.booleans())
def test_any_size_ratio_ends_near_the_target(guide, exponent, source_is_box):
    """Size ratios 1e-4..1e4 in either order (box and sphere); the warning exactly outside SIZE_RATIO_RANGE
    (ratios within a factor 2.5 of either bound are left out: the engine measures the sampled, upright source)."""
    assume(abs(abs(exponent) - 3.0) > 0.4)
    target, source = (_shape("sphere"), _shape("box")) if source_is_box else (_shape("box"), _shape("sphere"))
    source = _scaled(source, 10.0**exponent * _diagonal(target) / _diagonal(source))
    data = _aligned(_loaded(target), _loaded(source), guide)
    assert _codes(data) == (["scale_ratio_extreme"] if _expect_warning(10.0**exponent) else [])


@PROPERTY
@given(exponent=st.integers(-6, 6))
def test_any_absolute_scale_ends_near_the_target(guide, exponent):
    """Both meshes in micrometres to kilometres (a ratio of 1): no warning, the same kind of answer."""
    factor = 10.0**exponent
    data = _aligned(_loaded(_scaled(_shape("sphere"), factor)), _loaded(_scaled(_shape("box"), factor)), guide,
                    guided=False)
    assert _codes(data) == []
    assert data["transform"]["scale"] == pytest.approx(1.0)


@PROPERTY
@given(shape=st.sampled_from(["needle", "pancake", "triangle", "scatter"]), as_source=st.booleans(),
       exponent=st.sampled_from([-4.0, -2.0, 0.0, 2.0, 4.0]))
def test_degenerate_proportions_end_near_the_target(guide, shape, as_source, exponent):
    """Needles, pancakes, one triangle and scattered tiny triangles, as either mesh, at ratios 1e-4..1e4 to a
    box (a pancake target with a tiny source was the dense summit grid's worst case)."""
    odd, box = _shape(shape), _shape("box")
    source, target = (odd, box) if as_source else (box, odd)
    source = _scaled(source, 10.0**exponent * _diagonal(target) / _diagonal(source))
    data = _aligned(_loaded(target), _loaded(source), guide, guided=exponent != 0.0)
    assert _codes(data) == (["scale_ratio_extreme"] if _expect_warning(10.0**exponent) else [])


def _limit_data(limit: int):
    def apply():
        resource.setrlimit(resource.RLIMIT_DATA, (limit, resource.getrlimit(resource.RLIMIT_DATA)[1]))
    return apply


def test_the_issues_pair_runs_within_2_gb(tmp_path):
    """A sphere of radius 5000 (the target) and a 0.3 m box: the summit grid alone needed ~58 GB; now the whole
    CLI run fits a 2 GB data limit (RLIMIT_DATA), ends 0 and says why the answer is weak on stderr, in one line."""
    big, small = tmp_path / "big.ply", tmp_path / "small.glb"
    big.write_bytes(trimesh.creation.icosphere(subdivisions=3, radius=5000.0).export(file_type="ply"))
    trimesh.creation.box(extents=[0.3, 0.3, 0.3]).export(small)
    out, written = tmp_path / "scene.glb", tmp_path / "report.json"
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_WAIT_POLICY": "PASSIVE", "CTP_RUNTIME": "torch"}
    hard = resource.getrlimit(resource.RLIMIT_DATA)[1]
    limit = 2 * 2**30 if hard == resource.RLIM_INFINITY else min(2 * 2**30, hard)
    done = subprocess.run(
        [sys.executable, "-m", "ctp", "align", str(big), str(small), "--prompt", "a box on a ball", "--preset", "test",
         "--model", "random:tiny", "--quiet", "--out", str(out), "--report", str(written)],
        env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300, preexec_fn=_limit_data(limit))
    assert done.returncode == 0, done.stderr[-2000:]
    lines = [line for line in done.stderr.splitlines() if line.startswith("warning: scale_ratio_extreme: ")]
    assert len(lines) == 1, done.stderr
    data = json.loads(written.read_text())
    assert _codes(data) == ["scale_ratio_extreme"] and data["warnings"][0]["size_ratio"] < 1e-3
    assert np.isfinite(np.array(data["transform"]["matrix"])).all()
