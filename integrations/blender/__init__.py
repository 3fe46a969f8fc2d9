"""ctp in Blender: place the selected object relative to another from a prompt, with a ctp service.

A Blender extension (``blender_manifest.toml``; ``make blender-addon`` zips it). It talks to the service over HTTP
with the standard library only and moves the user's own object; docs/blender.md describes it."""

import bpy

from . import ops, props, ui

CLASSES = ops.CLASSES + ui.CLASSES


def register() -> None:
    props.register()
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.app.handlers.load_pre.append(ops.abandon)


def unregister() -> None:
    bpy.app.handlers.load_pre.remove(ops.abandon)
    ops.abandon()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
    props.unregister()
