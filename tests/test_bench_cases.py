"""Every benchmark case loads, renders and exports (needs the third-party assets in ../shared/bench)."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ctp_core import export, pairs
from ctp_core.align import AlignResult
from ctp_core.config import AlignConfig
from ctp_core.io import load_mesh
from ctp_core.render.structures import MeshArrays

BENCH = Path(__file__).resolve().parents[2] / "shared" / "bench"
CASES = sorted(p.parent for p in BENCH.glob("*/*/case.json"))
# cases per set, as ../shared/bench/README.md lists them: a set whose folder is present must hold all of its
# cases (a lost or half-copied case fails here, not as a silently smaller benchmark)
SET_SIZES = {"pairbench3d": 25, "synthetic": 8, "real": 32}


def _bench() -> list[Path]:
    if not CASES:
        pytest.skip(f"benchmark assets not found in {BENCH} (third-party files, not in the repository)")
    return CASES


def _placement(case: dict, target: trimesh.Trimesh, source: trimesh.Trimesh) -> np.ndarray:
    """The reference arrangement, or (no reference) the source set beside the target at its own scale."""
    if case["reference"] is not None:
        return np.asarray(case["reference"]["source_to_target"], dtype=float)
    matrix = np.eye(4)
    gap = (target.extents[0] + source.extents[0]) / 2
    matrix[:3, 3] = target.bounds.mean(0) + [gap, 0.0, 0.0] - source.bounds.mean(0)
    return matrix


def test_all_cases_load():
    cases = _bench()
    counted = {name: sum(folder.parent.name == name for folder in cases) for name in {c.parent.name for c in cases}}
    assert counted == {name: SET_SIZES.get(name) for name in counted}, f"cases per set: {counted}, expected {SET_SIZES}"
    for folder in cases:
        case = json.loads((folder / "case.json").read_text())
        for role in ("target", "source"):
            mesh = load_mesh(folder / case[role]["file"], name=f"{case['id']}/{role}")
            arrays = MeshArrays.from_trimesh(mesh)
            assert len(mesh.faces) > 0 and np.isfinite(arrays.vertices).all()
            assert arrays.colors.shape == arrays.vertices.shape
            assert arrays.texture is None or max(arrays.texture.shape[:2]) <= 2048


@pytest.mark.slow
def test_all_cases_render_and_export(tmp_path):
    config = AlignConfig.from_preset("test")
    for folder in _bench():
        case = json.loads((folder / "case.json").read_text())
        target, source = (load_mesh(folder / case[r]["file"], name=r) for r in ("target", "source"))
        placement = _placement(case, target, source)
        views = pairs.render_arrangement(target, source, placement, views=4, image_size=64)
        assert views.shape == (4, 3, 64, 64) and bool(views.isfinite().all())
        assert (views < 0.98).any(dim=1).float().mean() > 0.005, f"{case['id']}: nothing drawn"
        preview = (views.permute(0, 2, 3, 1).numpy() * 255).round().astype(np.uint8)
        result = AlignResult(source_to_target=placement, objective=0.0, target=target, source=source,
                             prompt=case["prompt"], config=config, priors={}, restarts=[], timings={},
                             preview=preview)
        out = tmp_path / case["id"]
        export.write_outputs(result, glb=out / "scene.glb", report_path=out / "report.json",
                             preview=out / "preview.png")
        loaded = trimesh.load(io.BytesIO((out / "scene.glb").read_bytes()), file_type="glb", force="scene")
        transform, geometry = loaded.graph["source"]
        placed = trimesh.transform_points(loaded.geometry[geometry].vertices, transform)
        expected = trimesh.transform_points(source.vertices, placement)
        assert np.abs(placed - expected).max() <= 1e-5 * np.ptp(expected, axis=0).max() + 1e-6, case["id"]
