"""The sidebar panel in the 3D view (N, tab "ctp"): the fields, Place or the job's progress and Cancel, then the
last placement: the verdict, the guide's say and the alternatives to step through."""

import textwrap

import bpy

from .ops import running
from .scene import SceneError, pick


def wrapped(layout: bpy.types.UILayout, context: bpy.types.Context, text: str, icon: str = "NONE") -> None:
    """``text`` as labels that fit the sidebar (a label does not wrap)."""
    width = max(20, context.region.width // 7) if context.region else 60
    column = layout.column(align=True)
    indent = "NONE" if icon == "NONE" else "BLANK1"  # later lines line up with the first's text
    for k, line in enumerate(textwrap.wrap(text, width) or [""]):
        column.label(text=line, icon=icon if k == 0 else indent)


class CTP_UL_alternatives(bpy.types.UIList):
    """One row per alternative: the answer first, each with its verdict; the active row is the one shown."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        layout.label(text=f"{item.label}: {item.verdict}")


class CTP_PT_place(bpy.types.Panel):
    bl_idname = "CTP_PT_place"
    bl_label = "Place from a Prompt"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "ctp"

    def draw(self, context: bpy.types.Context) -> None:
        layout, settings, state = self.layout, context.scene.ctp, context.window_manager.ctp_job
        layout.prop(settings, "target", text="Target")
        try:
            target, source = pick(context, settings.target)
            layout.label(text=f"place {source.name} relative to {target.name}", icon="OBJECT_DATA")
        except SceneError as exc:
            wrapped(layout, context, str(exc), "INFO")
        layout.prop(settings, "prompt", text="")
        layout.prop(settings, "preset")
        row = layout.row(align=True)
        row.prop(settings, "count")
        row.prop(settings, "arrangement", text="")
        if running() is not None:
            layout.progress(factor=state.fraction, type="BAR", text=state.message)
            layout.operator("ctp.cancel", icon="CANCEL")
        else:
            layout.operator("ctp.place", icon="PLAY")
            if state.message:
                wrapped(layout, context, state.message)
        if state.error:
            wrapped(layout.box(), context, state.error, "ERROR")
        self.draw_result(context)

    def draw_result(self, context: bpy.types.Context) -> None:
        result = context.scene.ctp_result
        if not result.summary:
            return
        box = self.layout.box()
        wrapped(box, context, result.summary, "CHECKMARK")
        wrapped(box, context, result.guide)
        if len(result.alternatives) > 1:
            box.template_list("CTP_UL_alternatives", "", result, "alternatives", result, "shown", rows=2)
            box.operator("ctp.keep", icon="PINNED")


CLASSES = (CTP_UL_alternatives, CTP_PT_place)
