"""The add-on's settings and state: the preferences (service URL, API key), the panel's fields (``scene.ctp``), the
last placement (``scene.ctp_result``: in the scene, so undo takes it back with the move) and the running job
(``window_manager.ctp_job``: outside undo, it follows the service)."""

import bpy
from bpy.props import (
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from .scene import show_alternative

# the service's presets and arrangements (docs/presets-and-search.md, docs/assembly.md)
PRESETS = [
    ("test", "Test", "A few steps: for smoke tests"),
    ("fast", "Fast", "The relation and the geometry choose, the guide glances"),
    ("default", "Default", "Search, then a short refinement: seconds a pair on a CPU worker"),
    ("descent", "Descent", "Local descent from random starts: about ten minutes a pair on a CPU"),
    ("paper", "Paper", "The paper's budget: meant for a GPU"),
]
ARRANGEMENTS = [
    ("auto", "Auto", "What the prompt says (around, in a row, a stack of), else scatter"),
    ("scatter", "Scatter", "Each copy placed by its own search on the scene so far"),
    ("around", "Around", "Evenly spaced around the target, facing it"),
    ("row", "Row", "Side by side along the target's longest side"),
    ("stack", "Stack", "Each copy on the one before"),
]


class Preferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    url: StringProperty(name="Service URL", default="http://127.0.0.1:8000",
                        description="Where the ctp service answers (`make serve` in the ctp repository)")
    api_key: StringProperty(name="API key", subtype="PASSWORD",
                            description="Sent as a bearer token where the service has API keys (CTP_API_KEYS)")

    def draw(self, context: bpy.types.Context) -> None:
        self.layout.prop(self, "url")
        self.layout.prop(self, "api_key")


def preferences(context: bpy.types.Context) -> Preferences:
    return context.preferences.addons[__package__].preferences


class Settings(bpy.types.PropertyGroup):
    target: PointerProperty(name="Target", type=bpy.types.Object, poll=lambda _self, obj: obj.type == "MESH",
                            description="What the selected object is placed relative to; empty: the active object")
    prompt: StringProperty(name="Prompt", description="The arrangement in words, e.g. 'a cup on the table'")
    preset: EnumProperty(name="Preset", items=PRESETS, default="default",
                         description="How long the service searches and refines")
    count: IntProperty(name="Count", min=0, max=12, default=0,
                       description="How many of the source to place (0: the prompt's number, else 1); the others "
                       "become linked duplicates")
    arrangement: EnumProperty(name="Arrangement", items=ARRANGEMENTS, default="auto",
                              description="How several of a kind are arranged")


class Alternative(bpy.types.PropertyGroup):
    label: StringProperty()
    verdict: StringProperty()
    matrix: FloatVectorProperty(size=(4, 4), subtype="MATRIX",
                                description="The report's source file -> target file transform (glTF frame)")


def _show(result: "Result", _context: bpy.types.Context) -> None:
    show_alternative(result, result.shown)


class Result(bpy.types.PropertyGroup):
    source: PointerProperty(type=bpy.types.Object)
    exported: FloatVectorProperty(size=(4, 4), subtype="MATRIX",
                                  description="The source's world matrix when it was exported")
    summary: StringProperty(description="The verdict on the prompt's relation")
    guide: StringProperty(description="Which guide ran, and its say in the choice")
    alternatives: CollectionProperty(type=Alternative)
    shown: IntProperty(name="Shown", update=_show, description="The alternative the source is at now")


class JobState(bpy.types.PropertyGroup):
    message: StringProperty()
    fraction: FloatProperty(min=0.0, max=1.0)
    error: StringProperty(description="Why the last placement did not happen")


CLASSES = (Preferences, Settings, Alternative, Result, JobState)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.ctp = PointerProperty(type=Settings)
    bpy.types.Scene.ctp_result = PointerProperty(type=Result)
    bpy.types.WindowManager.ctp_job = PointerProperty(type=JobState)


def unregister() -> None:
    del bpy.types.WindowManager.ctp_job
    del bpy.types.Scene.ctp_result
    del bpy.types.Scene.ctp
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
