"""Mesh input: every refusal has its code, and the supported formats keep geometry and appearance."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
import trimesh
from PIL import Image

from ctp_core.errors import ImageError, MeshError
from ctp_core.io import MeshLimits, load_image, load_mesh
from ctp_core.render.structures import MeshArrays


def _code(data, filename, **kwargs) -> str:
    with pytest.raises(MeshError) as info:
        load_mesh(data, filename=filename, **kwargs)
    assert info.value.field is None  # the service sets it
    return info.value.code


def _textured_box() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=(1.0, 2.0, 0.5))
    box.unmerge_vertices()  # one UV per face corner
    uv = np.tile([[0.1, 0.2], [0.9, 0.2], [0.5, 0.8]], (len(box.faces), 1))
    ramp = np.tile(np.arange(32, dtype=np.uint8) * 8, (16, 1))
    image = Image.fromarray(np.dstack([np.full((16, 32), 200, np.uint8), ramp, np.zeros((16, 32), np.uint8)]))
    material = trimesh.visual.material.PBRMaterial(baseColorTexture=image)
    box.visual = trimesh.visual.TextureVisuals(uv=uv, material=material)
    return box


def _glb(mesh_or_scene) -> bytes:
    return trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh_or_scene) if isinstance(mesh_or_scene, trimesh.Trimesh)
                                            else mesh_or_scene)


def _zip(members: dict[str, bytes]) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return buffer.getvalue()


_OBJ = b"""mtllib model.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
usemtl painted
f 1/1 2/2 3/3
f 1/1 3/3 4/4
"""


def _png(color) -> bytes:
    buffer = io.BytesIO()
    Image.new("RGB", (8, 8), color).save(buffer, format="PNG")
    return buffer.getvalue()


# --- what loads -----------------------------------------------------------------------------------

def test_textured_glb_round_trip_keeps_uv_and_texture():
    box = _textured_box()
    mesh = load_mesh(_glb(box), filename="box.GLB", name="target")
    assert mesh.metadata["name"] == "target"
    assert np.allclose(np.sort(mesh.extents), np.sort(box.extents))
    arrays = MeshArrays.from_trimesh(mesh)
    assert arrays.uv is not None and arrays.texture is not None
    assert arrays.texture.shape == (16, 32, 3)
    assert np.allclose(arrays.texture[0, :, 1], np.arange(32) * 8 / 255, atol=1 / 255)
    assert np.allclose(np.unique(np.round(arrays.uv, 4), axis=0), [[0.1, 0.2], [0.5, 0.8], [0.9, 0.2]])


def test_node_transforms_are_applied():
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name="moved",
                       transform=trimesh.transformations.translation_matrix([10.0, 0.0, 0.0]))
    scene.add_geometry(trimesh.creation.box(extents=(1, 1, 1)), node_name="origin")
    mesh = load_mesh(_glb(scene), filename="scene.glb")
    assert np.allclose(mesh.bounds, [[-0.5, -0.5, -0.5], [10.5, 0.5, 0.5]])
    assert len(mesh.faces) == 24


def test_obj_zip_with_mtl_and_texture_in_a_folder():
    members = {
        "model/model.obj": _OBJ,
        "model/model.mtl": b"newmtl painted\nKd 0.8 0.8 0.8\nmap_Kd textures\\Tex.png\n",
        "model/textures/tex.png": _png((255, 0, 0)),  # case differs from the MTL, as zips from Windows do
    }
    mesh = load_mesh(_zip(members), filename="upload.zip")
    arrays = MeshArrays.from_trimesh(mesh)
    assert len(mesh.faces) == 2
    assert arrays.texture is not None
    assert np.allclose(arrays.texture[..., 0], 1.0) and np.allclose(arrays.texture[..., 1], 0.0)
    assert arrays.uv is not None and arrays.uv.min() >= 0 and arrays.uv.max() <= 1


def test_obj_zip_reference_outside_the_archive_is_not_followed():
    members = {"model.obj": _OBJ, "model.mtl": b"newmtl painted\nKd 0.2 0.4 0.6\nmap_Kd ../../etc/passwd\n"}
    arrays = MeshArrays.from_trimesh(load_mesh(_zip(members), filename="upload.zip"))
    assert arrays.texture is None  # the escape resolved to nothing; the material colour is kept
    assert np.allclose(arrays.colors[0], [0.2, 0.4, 0.6], atol=1 / 255)


def test_ply_with_vertex_colours():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    colours = np.zeros((len(mesh.vertices), 4), np.uint8)
    colours[:, 0], colours[:, 3] = np.linspace(0, 255, len(mesh.vertices)).astype(np.uint8), 255
    mesh.visual.vertex_colors = colours
    loaded = load_mesh(mesh.export(file_type="ply"), filename="ball.ply")
    arrays = MeshArrays.from_trimesh(loaded)
    assert len(loaded.faces) == len(mesh.faces)
    assert np.allclose(np.sort(arrays.colors[:, 0]), np.sort(colours[:, 0] / 255), atol=1 / 255)


def test_stl_from_a_path(tmp_path):
    path = tmp_path / "part.stl"
    path.write_bytes(trimesh.creation.cylinder(radius=1, height=3, sections=12).export(file_type="stl"))
    mesh = load_mesh(path)
    assert np.allclose(mesh.extents, [2, 2, 3], atol=1e-6)
    assert load_mesh(path.read_bytes(), filename="part.stl").faces.shape == mesh.faces.shape


# --- refusals -------------------------------------------------------------------------------------

def test_unknown_format_and_missing_filename():
    assert _code(b"solid", "model.fbx") == "mesh_unknown_format"
    assert _code(b"solid", None) == "mesh_unknown_format"


def test_truncated_glb_and_random_bytes_are_unreadable():
    data = _glb(trimesh.creation.box())
    assert _code(data[: len(data) // 2], "box.glb") == "mesh_unreadable"
    noise = np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes()
    assert _code(noise, "noise.glb") == "mesh_unreadable"
    assert _code(noise, "noise.ply") == "mesh_unreadable"


def test_empty_inputs():
    assert _code(b"# nothing here\n", "empty.obj") == "mesh_empty"
    assert _code(_glb(trimesh.Scene()), "empty.glb") == "mesh_empty"
    degenerate = trimesh.Trimesh(np.zeros((3, 3)), [[0, 1, 2]], process=False)
    assert _code(degenerate.export(file_type="ply"), "point.ply") == "mesh_empty"


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # trimesh computes normals of the NaN face on load
def test_nan_vertices():
    text = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n" \
           b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"
    assert _code(text, "bad.ply") == "mesh_invalid_values"
    box = trimesh.creation.box()
    box.vertices[3] = np.inf
    assert _code(box.export(file_type="stl"), "bad.stl") == "mesh_invalid_values"


def test_face_budget_and_file_size():
    sphere = trimesh.creation.icosphere(subdivisions=4)  # 5120 faces
    data = sphere.export(file_type="stl")
    assert _code(data, "ball.stl", limits=MeshLimits(max_faces=5000)) == "mesh_too_large"
    assert load_mesh(data, filename="ball.stl", limits=MeshLimits(max_faces=5120)).faces.shape == (5120, 3)
    assert _code(data, "ball.stl", limits=MeshLimits(max_bytes=1000)) == "mesh_file_too_large"


def test_instances_count_against_the_face_budget():
    scene = trimesh.Scene()
    box = trimesh.creation.box()
    for i in range(3):
        scene.add_geometry(box, geom_name="box", node_name=f"n{i}",
                           transform=trimesh.transformations.translation_matrix([2.0 * i, 0, 0]))
    assert _code(_glb(scene), "boxes.glb", limits=MeshLimits(max_faces=30)) == "mesh_too_large"


def test_gltf_with_external_references_is_refused_unread(tmp_path):
    secret = tmp_path / "model.bin"
    secret.write_bytes(b"\0" * 64)
    tree = {"asset": {"version": "2.0"}, "buffers": [{"uri": "model.bin", "byteLength": 64}]}
    gltf = tmp_path / "model.gltf"
    gltf.write_text(json.dumps(tree))
    assert _code(gltf, None) == "mesh_external_reference"  # even by path, with the file right there
    tree["buffers"][0]["uri"] = "https://example.com/model.bin"
    assert _code(json.dumps(tree).encode(), "model.gltf") == "mesh_external_reference"

    # a GLB whose image points at a local file
    data = bytearray(_glb(_textured_box()))
    length = int.from_bytes(data[12:16], "little")
    header = json.loads(data[20:20 + length])
    header["images"] = [{"uri": "/etc/passwd"}]
    chunk = json.dumps(header).encode()
    chunk += b" " * (-len(chunk) % 4)
    rest = data[20 + length:]
    glb = b"glTF" + (2).to_bytes(4, "little") + (20 + len(chunk) + len(rest)).to_bytes(4, "little") \
        + len(chunk).to_bytes(4, "little") + b"JSON" + chunk + rest
    assert _code(bytes(glb), "model.glb") == "mesh_external_reference"


def test_bad_zips():
    assert _code(b"PK\x03\x04 not really", "x.zip") == "mesh_zip_invalid"
    assert _code(_zip({"../evil.obj": _OBJ}), "x.zip") == "mesh_zip_invalid"
    assert _code(_zip({"readme.txt": b"hi"}), "x.zip") == "mesh_zip_invalid"
    assert _code(_zip({"a.obj": _OBJ, "b.obj": _OBJ}), "x.zip") == "mesh_zip_invalid"
    bomb = _zip({"model.obj": _OBJ, "model.mtl": b"\0" * (4 * 2**20)})  # 4 MiB of zeros packs to ~4 KiB
    assert len(bomb) < 50_000
    assert _code(bomb, "x.zip", limits=MeshLimits(max_unzipped_bytes=2**20)) == "mesh_zip_invalid"
    many = _zip({f"t{i}.png": b"x" for i in range(5)} | {"model.obj": _OBJ})
    assert _code(many, "x.zip", limits=MeshLimits(max_zip_members=4)) == "mesh_zip_invalid"


def test_multi_material_scene_keeps_its_colours():
    """Two textured parts flatten into one atlas; each part still samples its own colour (not inverted)."""
    scene = trimesh.Scene()
    for name, colour, x in (("red", (220, 30, 20), 0.0), ("blue", (20, 40, 230), 3.0)):
        part = trimesh.creation.box()
        part.unmerge_vertices()
        material = trimesh.visual.material.PBRMaterial(baseColorTexture=Image.new("RGB", (8, 8), colour),
                                                       baseColorFactor=[255, 255, 255, 255])
        part.visual = trimesh.visual.TextureVisuals(uv=np.full((len(part.vertices), 2), 0.5), material=material)
        scene.add_geometry(part, node_name=name, transform=trimesh.transformations.translation_matrix([x, 0, 0]))
    arrays = MeshArrays.from_trimesh(load_mesh(_glb(scene), filename="parts.glb"))
    height, width = arrays.texture.shape[:2]
    texel = arrays.texture[((1 - arrays.uv[:, 1]) * (height - 1)).round().astype(int),
                           (arrays.uv[:, 0] * (width - 1)).round().astype(int)] * arrays.colors
    left = arrays.vertices[:, 0] < 1.5
    assert np.allclose(texel[left], np.array([220, 30, 20]) / 255, atol=0.02)
    assert np.allclose(texel[~left], np.array([20, 40, 230]) / 255, atol=0.02)


def _rgb_png(width: int, height: int) -> bytes:
    out = io.BytesIO()
    Image.new("RGB", (width, height), (10, 200, 30)).save(out, format="PNG")
    return out.getvalue()


def test_load_image_from_bytes_and_path(tmp_path):
    picture = _rgb_png(8, 6)
    (tmp_path / "ref.png").write_bytes(picture)
    for data in (picture, tmp_path / "ref.png"):
        image = load_image(data)
        assert image.shape == (6, 8, 3) and image.dtype == np.uint8 and tuple(image[0, 0]) == (10, 200, 30)


def test_load_image_refusals_have_one_clear_message(tmp_path):
    with pytest.raises(ImageError) as bad:
        load_image(b"not a picture")
    assert (bad.value.code, bad.value.message) == ("invalid_image", "image: not a readable PNG or JPEG image")
    with pytest.raises(ImageError) as truncated:
        load_image(_rgb_png(64, 64)[:60])
    assert truncated.value.message == bad.value.message  # whatever PIL raised, the same words
    with pytest.raises(ImageError) as big:
        load_image(_rgb_png(100, 100), max_pixels=9999)
    assert big.value.code == "image_too_large" and "100 x 100" in big.value.message
    with pytest.raises(ImageError, match="no such file: .*nope.png"):
        load_image(tmp_path / "nope.png")


# --- glTF budgets, read from the JSON before any geometry is built ----------------------------------

_TRIANGLE = np.array([0, 0, 0, 1, 0, 0, 0, 1, 0], "<f4").tobytes()


def _gltf(**change) -> bytes:
    """A one-triangle .gltf with an embedded buffer; ``change`` replaces top-level entries."""
    import base64

    tree = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "buffers": [{"uri": "data:application/octet-stream;base64," + base64.b64encode(_TRIANGLE).decode(),
                         "byteLength": 36}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                           "min": [0, 0, 0], "max": [1, 1, 0]}]}
    tree.update(change)
    return json.dumps(tree).encode()


def test_gltf_budgets_and_consistency():
    assert load_mesh(_gltf(), filename="t.gltf").faces.shape == (1, 3)
    chain = [{"children": [i + 1]} for i in range(200)] + [{"mesh": 0}]
    assert _code(_gltf(nodes=chain), "t.gltf") == "mesh_too_complex"  # 201 deep, over 128
    assert load_mesh(_gltf(nodes=chain), filename="t.gltf", limits=MeshLimits(max_depth=300)).faces.shape == (1, 3)
    assert _code(_gltf(nodes=chain), "t.gltf", limits=MeshLimits(max_nodes=100, max_depth=300)) == "mesh_too_complex"
    cycle = [{"children": [1]}, {"children": [0], "mesh": 0}]
    assert _code(_gltf(nodes=cycle, scenes=[{"nodes": []}]), "t.gltf") == "mesh_too_complex"  # endless depth
    two_parents = [{"children": [2]}, {"children": [2]}, {"mesh": 0}]
    assert _code(_gltf(nodes=two_parents, scenes=[{"nodes": [0, 1]}]), "t.gltf") == "mesh_unreadable"
    fan = [{"children": list(range(1, 1001))}] + [{"mesh": 0}] * 1000  # 1000 instances of one triangle
    assert _code(_gltf(nodes=fan), "t.gltf", limits=MeshLimits(max_faces=999)) == "mesh_too_large"
    accessor = {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3"}  # 48 bytes of a 36-byte view
    assert _code(_gltf(accessors=[accessor]), "t.gltf") == "mesh_unreadable"
    assert _code(_gltf(bufferViews=[{"buffer": 0, "byteOffset": 4, "byteLength": 36}]), "t.gltf") == "mesh_unreadable"
    short = [{"uri": "data:application/octet-stream;base64,AAAA", "byteLength": 36}]
    assert _code(_gltf(buffers=short), "t.gltf") == "mesh_unreadable"
    assert _code(_gltf(nodes="many"), "t.gltf") == "mesh_unreadable"
    assert _code(b"[" * 100_000 + b"]" * 100_000, "t.gltf") == "mesh_unreadable"  # no RecursionError escapes


def test_zip_symlink_member_is_refused():
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        archive.writestr("m.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        link = zipfile.ZipInfo("texture.png")
        link.external_attr = 0o120777 << 16
        archive.writestr(link, "/etc/passwd")
    assert _code(out.getvalue(), "m.zip") == "mesh_zip_invalid"

