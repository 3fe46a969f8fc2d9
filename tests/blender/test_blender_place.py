"""The add-on in real headless Blender against a live ``ctp serve`` (test preset, tiny random model): the cup ends
on the table in Blender's own coordinates, in one undo step, with its materials, modifiers and links; copies,
alternatives, a parented and scaled source, cancel, and the errors a user sees."""

import json
import os
import threading
import time
import urllib.request
import zipfile
from pathlib import Path

import bmesh
import bpy
import numpy
import pytest
from conftest import (
    REPO,
    free_port,
    make_cup,
    make_table,
    new_object,
    on_table_top,
    place,
    read_glb,
    select,
    upright,
)
from mathutils import Euler, Matrix, Quaternion, Vector

PICTURE = os.environ.get("CTP_BLENDER_PICTURE")  # where the docs' picture goes (make docs-blender); else tmp


def snapshot() -> dict[str, tuple]:
    """Every object's name, world matrix, mesh, materials and modifiers: what 'untouched' compares."""
    bpy.context.view_layer.update()
    return {o.name: (tuple(map(tuple, o.matrix_world)), o.data.name if o.data else None,
                     tuple(m.name for m in o.material_slots), tuple(m.name for m in o.modifiers))
            for o in bpy.data.objects}


def test_blender_places_the_cup_on_the_table(scene, tmp_path):
    table, cup = make_table(), make_cup()
    select(table, cup)
    bpy.ops.ed.undo_push(message="the scene as built")
    before = snapshot()

    assert place("a cup on the table") == {"FINISHED"}

    cup, table = bpy.data.objects["Cup"], bpy.data.objects["Table"]
    on_table_top(cup, table)
    assert upright(cup) > 0.99  # its own +Z (its up, as exported) points up again
    after = snapshot()
    assert set(after) == set(before)  # nothing imported, nothing replaced
    assert after["Table"] == before["Table"]
    assert after["Cup"][1:] == before["Cup"][1:]  # the same mesh, materials and modifiers
    result = scene.ctp_result
    assert result.summary.startswith("'on' holds, stable, touching"), result.summary
    assert result.guide.startswith("guide: random:tiny"), result.guide
    assert bpy.context.window_manager.ctp_job.error == ""
    render(scene, table, tmp_path)

    bpy.ops.ed.undo()  # one step takes the placement back whole
    assert snapshot() == before
    bpy.ops.ed.redo()
    on_table_top(bpy.data.objects["Cup"], bpy.data.objects["Table"])


def render(scene: bpy.types.Scene, table: bpy.types.Object, tmp_path: Path) -> None:
    """The result as Blender's Workbench renders it headless: the docs' picture."""
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    camera.location = table.matrix_world @ Vector((1.6, -1.9, 1.5))
    look = table.location + Vector((0, 0, 0.45)) - camera.location
    camera.rotation_euler = look.to_track_quat("-Z", "Y").to_euler()
    scene.camera = camera
    scene.world = bpy.data.worlds.new("World")
    scene.world.color = (0.75, 0.78, 0.82)  # the background Workbench renders
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.shading.color_type = "MATERIAL"
    scene.render.resolution_x, scene.render.resolution_y = 400, 260
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.compression = 100
    scene.render.dither_intensity = 0.0  # no noise: a small PNG
    scene.render.filepath = PICTURE or str(tmp_path / "blender-result.png")
    bpy.ops.render.render(write_still=True)
    bpy.data.objects.remove(camera)
    picture = bpy.data.images.load(scene.render.filepath)
    pixels = numpy.empty(len(picture.pixels), dtype=numpy.float32)
    picture.pixels.foreach_get(pixels)
    r, g, b = (pixels.reshape(-1, 4)[:, i] for i in range(3))
    assert ((b > r + 0.2) & (b > g + 0.1)).sum() > 50  # the blue cup is in the picture
    bpy.data.images.remove(picture)


def test_blender_alternatives_step_and_keep(scene, addon):
    table, cup = make_table(), make_cup()
    select(table, cup)
    assert place("a cup on the table") == {"FINISHED"}
    result = scene.ctp_result
    assert len(result.alternatives) >= 2 and result.alternatives[0].label == "answer"
    answer = cup.matrix_world.copy()

    result.shown = 1  # a click on the list's second row
    bpy.context.view_layer.update()
    expected = addon.frames.placed_world(result.alternatives[1].matrix, result.exported)
    assert _close(cup.matrix_world, expected)
    assert not _close(cup.matrix_world, answer)
    assert bpy.ops.ctp.keep("EXEC_DEFAULT", True) == {"FINISHED"}
    assert len(result.alternatives) == 0
    assert _close(cup.matrix_world, expected)  # kept where it was shown


def _close(a: Matrix, b: Matrix, tol: float = 1e-5) -> bool:
    return all(abs(a[i][j] - b[i][j]) < tol for i in range(4) for j in range(4))


def test_blender_parented_and_scaled_source(scene):
    table = make_table()
    tray = bpy.data.objects.new("Tray", None)  # an empty the cup is parented to: turned, moved, scaled
    scene.collection.objects.link(tray)
    tray.location, tray.rotation_euler, tray.scale = (-3.0, 1.0, 0.5), (0.2, -0.4, 0.7), (1.5, 1.5, 1.5)
    cup = make_cup(location=(0.3, 0.2, 0.1), rotation=(0.0, 0.9, 0.0))
    cup.scale = (0.8, 0.8, 1.25)
    bpy.context.view_layer.update()
    cup.parent = tray
    select(table, cup)
    world_scale = cup.matrix_world.to_scale()  # 1.5 x its own

    assert place("a cup on the table") == {"FINISHED"}

    bpy.context.view_layer.update()
    assert cup.parent == tray and tray.matrix_world.to_scale() == Vector((1.5, 1.5, 1.5))
    assert (cup.scale - Vector((0.8, 0.8, 1.25))).length < 1e-4  # its own scale, under the same parent
    assert (cup.matrix_world.to_scale() - world_scale).length < 1e-4
    on_table_top(cup, table)
    assert upright(cup) > 0.99


def test_blender_copies_are_linked_duplicates(scene):
    table, cup = make_table(), make_cup()
    select(table, cup)
    assert place("two cups on the table", count=2) == {"FINISHED"}
    cups = [o for o in bpy.data.objects if o.data == cup.data]
    assert len(cups) == 2 and cup in cups  # the source and one linked duplicate sharing its mesh
    duplicate = next(o for o in cups if o != cup)
    assert [m.name for m in duplicate.modifiers] == ["Bevel"] and duplicate.users_collection == cup.users_collection
    for each in cups:
        on_table_top(each, table)
    assert (cups[0].matrix_world.translation - cups[1].matrix_world.translation).length > 0.05
    assert scene.ctp_result.summary.startswith("2 of 2 copies"), scene.ctp_result.summary


def test_blender_cancel_leaves_the_scene_untouched(scene, addon, service):
    table, cup = make_table(), make_cup()
    select(table, cup)
    before = snapshot()
    canceled = {}

    def press_cancel():  # what Cancel does, once the job is on the service
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            job = addon.ops.running()
            if job is not None and job.job_id is not None:
                canceled["id"] = job.job_id
                job.cancel()
                return
            time.sleep(0.05)

    presser = threading.Thread(target=press_cancel)
    presser.start()
    assert place("a cup on the table", preset="default") == {"CANCELLED"}
    presser.join()

    assert snapshot() == before
    assert scene.ctp_result.summary == "" and addon.ops.running() is None
    with urllib.request.urlopen(f"{service}/jobs/{canceled['id']}", timeout=10) as answer:
        job = json.loads(answer.read())
    assert job["status"] == "canceled" or job["cancel_requested"], job


def test_blender_unreachable_service_says_how_to_start_it(scene, addon):
    table, cup = make_table(), make_cup()
    select(table, cup)
    url = f"http://127.0.0.1:{free_port()}"
    bpy.context.preferences.addons[addon.__name__].preferences.url = url
    before = snapshot()
    with pytest.raises(RuntimeError) as raised:
        place("a cup on the table")
    message = str(raised.value)
    assert url in message and "make serve" in message and "Traceback" not in message
    assert bpy.context.window_manager.ctp_job.error in message
    assert snapshot() == before


def test_blender_refused_mesh_gives_the_service_message(scene):
    table = make_table()
    flat = new_object("Sticker", bmesh.new(), (1, 1, 1, 1))  # a mesh with no faces: the service refuses it
    select(table, flat)
    with pytest.raises(RuntimeError) as raised:
        place("a sticker on the table")
    message = str(raised.value)  # the object named, the service's own words and code
    assert "Sticker: " in message and "no triangles" in message and "(mesh_empty)" in message, message
    assert "Traceback" not in message


def test_blender_export_frame_is_the_one_placed_world_undoes(scene, addon, tmp_path):
    """The glTF exporter's frame, read back from the GLB: file = Y_UP @ frame @ object-local, the assumption
    ``frames.placed_world`` inverts. Then placed_world itself: the identity leaves the source where exported, and
    glTF's +Y is Blender's +Z."""
    mesh = bmesh.new()
    bmesh.ops.create_cube(mesh, size=1.0, matrix=Matrix.Diagonal((0.1, 0.2, 0.3, 1.0)))
    obj = new_object("Brick", mesh, (1, 1, 1, 1))
    frame = Matrix.LocRotScale((1.0, 2.0, 3.0), Euler((0.3, 0.2, 0.9)), (1.0, 1.0, 1.0))
    addon.scene.export_object(bpy.context, obj, frame, tmp_path / "brick.glb")
    gltf = read_glb(tmp_path / "brick.glb")
    (node,) = gltf["nodes"]
    node_matrix = Matrix.LocRotScale(node.get("translation", (0, 0, 0)),
                                     _quaternion(node.get("rotation", (0, 0, 0, 1))), node.get("scale", (1, 1, 1)))
    low, high = (Vector(gltf["accessors"][0][k]) for k in ("min", "max"))
    corners = [Vector((x, y, z)) for x in (low.x, high.x) for y in (low.y, high.y) for z in (low.z, high.z)]
    in_file = sorted(tuple(round(c, 4) for c in node_matrix @ p) for p in corners)
    blender_local = [Vector((x, y, z)) for x in (-0.05, 0.05) for y in (-0.1, 0.1) for z in (-0.15, 0.15)]
    expected = sorted(tuple(round(c, 4) for c in addon.frames.Y_UP @ frame @ p) for p in blender_local)
    assert in_file == expected
    assert "Brick" in bpy.data.objects and len(bpy.data.objects) == 1  # the stand-in is gone

    identity = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    assert _close(addon.frames.placed_world(identity, frame), frame)
    up_one = [[1, 0, 0, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]]
    assert _close(addon.frames.placed_world(up_one, frame), Matrix.Translation((0, 0, 1)) @ frame)


def _quaternion(xyzw) -> Quaternion:
    x, y, z, w = xyzw  # glTF's order
    return Quaternion((w, x, y, z))


def test_blender_extension_zip_lists_the_add_on(addon):
    """The zip ``make blender-addon`` builds holds the manifest at its root and every module of the add-on."""
    archive = next((REPO / "dist").glob("ctp_place-*.zip"))
    names = set(zipfile.ZipFile(archive).namelist())
    sources = {p.name for p in (REPO / "integrations" / "blender").iterdir() if p.suffix in (".py", ".toml")}
    assert names == sources and "blender_manifest.toml" in names
