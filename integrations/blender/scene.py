"""The user's scene: which objects a placement is about, their export to GLB, and the result put back into the
scene by moving the source (never by importing: its materials, modifiers, parent and links stay)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import bpy
from mathutils import Matrix

from .frames import placed_world
from .report import guide, placements, summary


class SceneError(Exception):
    """Objects the add-on cannot place, in words for the user."""


def pick(context: bpy.types.Context, picked: bpy.types.Object | None) -> tuple[bpy.types.Object, bpy.types.Object]:
    """The target (the one picked in the panel, else the active object) and the source (the one other selected)."""
    layer = context.view_layer  # not context.selected_objects: scripts and background mode have no screen context
    target = picked or layer.objects.active
    if target is None:
        raise SceneError("no target: make it the active object, or pick it in the panel")
    sources = [o for o in layer.objects if o.select_get() and o != target]
    if len(sources) != 1:
        raise SceneError(f"select exactly one object to place besides the target {target.name} "
                         f"({len(sources)} selected)")
    for role, obj in (("target", target), ("source", sources[0])):
        if obj.type != "MESH":
            raise SceneError(f"the {role}, {obj.name}, is {obj.type.lower()}, not a mesh")
    return target, sources[0]


def export_pair(context: bpy.types.Context, target: bpy.types.Object, source: bpy.types.Object,
                folder: Path) -> Matrix:
    """``target.glb`` and ``source.glb`` in ``folder``: the target where it stands in the world, the source in its own
    axes (its local +Z its up, its world scale kept, its place and turn left out: the service poses it). Returns
    the source's export frame, which ``frames.placed_world`` needs."""
    frame = Matrix.LocRotScale(None, None, source.matrix_world.to_scale())
    export_object(context, target, target.matrix_world, folder / "target.glb")
    export_object(context, source, frame, folder / "source.glb")
    return frame


def export_object(context: bpy.types.Context, obj: bpy.types.Object, frame: Matrix, path: Path) -> None:
    """``obj``'s evaluated mesh (modifiers applied) with its materials as a GLB, at ``frame`` (object -> Blender world
    axes; the exporter turns them to glTF's +Y up, ``frames.Y_UP``). A stand-in object is exported and removed, so
    the user's object, its links and the selection are as they were."""
    mesh = bpy.data.meshes.new_from_object(obj.evaluated_get(context.evaluated_depsgraph_get()))
    stand_in = bpy.data.objects.new(obj.name, mesh)
    stand_in.matrix_world = frame
    context.scene.collection.objects.link(stand_in)
    layer = context.view_layer
    selected = [o for o in layer.objects if o.select_get()]
    active = layer.objects.active
    try:
        for o in selected:
            o.select_set(False)
        stand_in.select_set(True)
        bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLB", use_selection=True, export_yup=True,
                                  export_animations=False, export_cameras=False, export_lights=False)
    finally:
        bpy.data.objects.remove(stand_in)
        bpy.data.meshes.remove(mesh)
        for o in selected:
            o.select_set(True)
        layer.objects.active = active
    if not path.is_file():
        raise SceneError(f"{obj.name} could not be exported")


def apply_result(scene: bpy.types.Scene, source: bpy.types.Object, exported: Matrix,
                 report: dict[str, Any]) -> list[bpy.types.Object]:
    """The report into the scene (``exported``: the source's export frame): the source moved to the answer, kept
    in ``scene.ctp_result`` with its alternatives to step through; for several of a kind, to the first copy, with a
    linked duplicate at each other copy. Returns the objects placed."""
    found = placements(report)
    copies = bool(report.get("copies"))
    placed = found if copies else found[:1]
    objects = [source] + [linked_duplicate(source) for _ in placed[1:]]
    for obj, placement in zip(objects, placed, strict=True):
        obj.matrix_world = placed_world(placement.matrix, exported)
    result = scene.ctp_result
    result.alternatives.clear()
    for placement in [] if copies else found:
        alternative = result.alternatives.add()
        alternative.label, alternative.verdict = placement.label, placement.verdict
        alternative.matrix = Matrix(placement.matrix)
    result.source, result.exported = source, exported
    result.summary, result.guide = summary(report), guide(report)
    result["shown"] = 0  # the answer, set without the update that would move the source again
    return objects


def linked_duplicate(obj: bpy.types.Object) -> bpy.types.Object:
    """As Alt+D: a new object sharing ``obj``'s mesh (and so its materials), with its modifiers and parent, in the
    same collections."""
    duplicate = obj.copy()
    for collection in obj.users_collection:
        collection.objects.link(duplicate)
    return duplicate


def show_alternative(result: Any, index: int) -> None:
    """The source moved to alternative ``index`` of the last placement (the update of ``ctp_result.shown``)."""
    if result.source is not None and 0 <= index < len(result.alternatives):
        result.source.matrix_world = placed_world(result.alternatives[index].matrix, result.exported)
