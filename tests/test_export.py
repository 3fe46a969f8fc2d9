"""Export: the GLB reproduces the placed source, the report recomposes the transform, the sheet tiles."""

from __future__ import annotations

import datetime as dt
import io
import json

import numpy as np
import pytest
import trimesh
from PIL import Image
from scipy.spatial.transform import Rotation

from ctp_core.align import AlignResult
from ctp_core.config import AlignConfig
from ctp_core.export import preview_png, report, scene_glb, write_outputs
from ctp_core.orientation import canonical


def _textured(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.unmerge_vertices()
    uv = np.random.default_rng(0).uniform(size=(len(mesh.vertices), 2))
    image = Image.fromarray(np.full((8, 8, 3), (10, 200, 30), np.uint8))
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=image)
    mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return mesh


def _result(preview: np.ndarray | None = None) -> AlignResult:
    target = trimesh.creation.box(extents=(40.0, 10.0, 30.0))
    target.visual.vertex_colors = [200, 50, 50, 255]
    source = _textured(trimesh.creation.icosphere(subdivisions=2, radius=3.0).apply_translation([100.0, -5.0, 2.0]))
    matrix = np.eye(4)
    matrix[:3, :3] = 0.7 * Rotation.from_euler("xyz", [10, 70, -30], degrees=True).as_matrix()
    matrix[:3, 3] = [-60.0, 12.0, 5.0]
    return AlignResult(
        source_to_target=matrix, objective=-0.31, target=target, source=source, prompt="a ball on a box",
        config=AlignConfig.from_preset("test", seed=3), priors={"size_ratio": np.float32(0.2)},
        restarts=[{"restart": 0, "objective": -0.31}], timings={"total_s": 1.5}, preview=preview,
        model="random:tiny", best_restart=0, clip_images=np.int64(12),
        phase_timings=[{"phase_s": np.float32(0.5)}], target_upright=canonical.identity(),
    )


def test_glb_places_the_source_and_keeps_names_and_materials():
    result = _result()
    scene = trimesh.load(io.BytesIO(scene_glb(result)), file_type="glb", force="scene")
    assert {"target", "source"} <= set(scene.graph.nodes_geometry)
    placed = {}
    for node in ("target", "source"):
        transform, geometry = scene.graph[node]
        placed[node] = trimesh.transform_points(scene.geometry[geometry].vertices, transform), scene.geometry[geometry]
    expected = trimesh.transform_points(result.source.vertices, result.source_to_target)
    size = np.ptp(expected, axis=0).max()
    assert np.abs(placed["source"][0] - expected).max() < 1e-5 * size
    target_size = np.ptp(result.target.vertices, axis=0).max()
    assert np.abs(placed["target"][0] - result.target.vertices).max() < 1e-5 * target_size
    texture = placed["source"][1].visual.material.baseColorTexture
    assert texture is not None and np.asarray(texture.convert("RGB"))[0, 0].tolist() == [10, 200, 30]
    assert placed["target"][1].visual.vertex_colors[0, :3].tolist() == [200, 50, 50]


def test_report_is_json_and_recomposes_the_transform():
    result = _result()
    data = json.loads(json.dumps(report(result)))
    transform = data["transform"]
    assert (transform["from_frame"], transform["to_frame"]) == ("source_file", "target_file")
    w, x, y, z = transform["rotation_wxyz"]
    rebuilt = np.eye(4)
    rebuilt[:3, :3] = transform["scale"] * Rotation.from_quat([x, y, z, w]).as_matrix()
    rebuilt[:3, 3] = transform["translation"]
    assert np.allclose(rebuilt, result.source_to_target, atol=1e-9)
    assert np.allclose(transform["matrix"], result.source_to_target)
    assert data["prompt"] == "a ball on a box" and data["model"] == "random:tiny"
    assert data["seed"] == 3 and data["preset"] == "test" and data["config"]["seed"] == 3
    assert data["extra"]["clip_images"] == 12 and data["extra"]["phase_timings"] == [{"phase_s": 0.5}]
    assert data["extra"]["target_upright"] == {"rotation": np.eye(3).tolist(), "changed": False, "up": [0, 1, 0],
                                               "front": [0, 0, 1], "front_trusted": False,
                                               "reason": "not canonicalised",
                                               "front_reason": "no front given: the file's +Z, not trusted"}
    assert data["hparams"]["size_ratio"] == pytest.approx(0.2)
    assert {"ctp", "torch", "trimesh", "python"} <= set(data["versions"])
    assert dt.datetime.fromisoformat(data["created_at"]).tzinfo is not None


@pytest.mark.parametrize("views, grid", [(4, (2, 2)), (3, (2, 2)), (1, (1, 1)), (6, (2, 3))])
def test_preview_contact_sheet(views, grid):
    images = np.zeros((views, 20, 30, 3), np.uint8)
    for i in range(views):
        images[i] = 10 * (i + 1)
    sheet = np.asarray(Image.open(io.BytesIO(preview_png(images))))
    rows, cols = grid
    assert sheet.shape == (rows * 20, cols * 30, 3)
    for i in range(rows * cols):
        r, c = divmod(i, cols)
        assert (sheet[r * 20:(r + 1) * 20, c * 30:(c + 1) * 30] == (10 * (i + 1) if i < views else 255)).all()
    with pytest.raises(ValueError):
        preview_png(images.astype(np.float32))


def test_write_outputs(tmp_path):
    result = _result(preview=np.full((4, 16, 16, 3), 128, np.uint8))
    paths = tmp_path / "out" / "scene.glb", tmp_path / "report.json", tmp_path / "preview.png"
    write_outputs(result, glb=paths[0], report_path=paths[1], preview=paths[2])
    assert trimesh.load(paths[0], force="scene").graph.nodes_geometry
    assert json.loads(paths[1].read_text())["objective"] == pytest.approx(-0.31)
    assert Image.open(paths[2]).size == (32, 32)
    write_outputs(result, glb=None, report_path=None, preview=None)  # nothing asked, nothing written
    with pytest.raises(ValueError, match="preview"):
        write_outputs(_result(), glb=None, report_path=None, preview=tmp_path / "p.png")
