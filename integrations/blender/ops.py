"""The operators: Place (export, submit, follow, apply as one undo step), Cancel, and Keep (one alternative).

Place from the panel (invoke) follows the job with a modal timer, so Blender stays responsive; from a script or
in background mode (execute) it waits for the job where it is. Errors are reported as one line, never a
traceback."""

import json
import shutil
import tempfile
from pathlib import Path

import bpy

from .client import Client
from .job import Job
from .names import object_name
from .props import preferences
from .scene import SceneError, apply_result, export_pair, pick

TICK_S = 0.25
_running: Job | None = None  # the one job being followed; Cancel reaches it here


def running() -> Job | None:
    return _running


@bpy.app.handlers.persistent
def abandon(*_args) -> None:
    """Cancels the job being followed: on unregister, and when a file is opened during it (which ends the modal
    operator without a word), so that Place works again."""
    global _running
    if _running is not None:
        _running.cancel()
        _running = None


class CTP_OT_place(bpy.types.Operator):
    """Place the selected object relative to the target as the prompt says, with the ctp service"""

    bl_idname = "ctp.place"
    bl_label = "Place"
    bl_options = {"UNDO"}  # one undo step, pushed when the result is applied (not REGISTER: no redo that reruns it)

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        return context.mode == "OBJECT" and _running is None

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        if not self._start(context):
            return {"CANCELLED"}
        wm = context.window_manager
        self.timer = wm.event_timer_add(TICK_S, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        state = context.window_manager.ctp_job
        state.message, state.fraction = self.job.message, self.job.fraction
        context.workspace.status_text_set(f"ctp: {state.message} ({state.fraction:.0%})")
        for area in context.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()
        if not self.job.ended.is_set():
            return {"PASS_THROUGH"}
        context.window_manager.event_timer_remove(self.timer)
        context.workspace.status_text_set(None)
        return self._finish(context)

    def execute(self, context: bpy.types.Context) -> set[str]:
        if not self._start(context):
            return {"CANCELLED"}
        self.job.join()
        return self._finish(context)

    def _start(self, context: bpy.types.Context) -> bool:
        """Exports the pair and starts the job's thread; False (reported) when that cannot be done."""
        global _running
        state, settings = context.window_manager.ctp_job, context.scene.ctp
        state.error = ""
        folder = Path(tempfile.mkdtemp(prefix="ctp-blender-"))  # the job removes it when it ends
        try:
            target, source = pick(context, settings.target)
            if not settings.prompt.strip():
                raise SceneError("write a prompt, e.g. 'a cup on the table'")
            self.exported = export_pair(context, target, source, folder)
        except Exception as exc:  # SceneError, the glTF exporter's RuntimeError, anything else: one line
            shutil.rmtree(folder, ignore_errors=True)
            self._fail(state, str(exc) or type(exc).__name__)
            return False
        self.source_name = source.name
        options = {"preset": settings.preset}
        if settings.count:
            options["count"] = settings.count
        if settings.arrangement != "auto":
            options["arrangement"] = settings.arrangement
        fields = {"prompt": settings.prompt, "options": json.dumps(options)}
        for role, obj in (("target", target), ("source", source)):  # unnamed: the service reads the file's
            name = object_name(obj.name, obj.data.name)
            if name is not None:
                fields[f"{role}_name"] = name
        prefs = preferences(context)
        self.job = _running = Job(Client(prefs.url, prefs.api_key), folder, folder / "target.glb",
                                  folder / "source.glb", fields)
        self.job.start()
        state.message, state.fraction = "uploading", 0.0
        return True

    def _finish(self, context: bpy.types.Context) -> set[str]:
        """The ended job into the scene: its placement (FINISHED: the undo step), or its error (CANCELLED)."""
        global _running
        if _running is self.job:
            _running = None
        job, state = self.job, context.window_manager.ctp_job
        if job.canceled:
            state.message = "canceled: the scene is as it was"
            self.report({"INFO"}, f"ctp: {state.message}")
            return {"CANCELLED"}
        source = bpy.data.objects.get(self.source_name)
        if job.error is None and source is None:
            job.error = f"the source object {self.source_name} is gone (renamed or deleted during the job)"
        if job.error is not None:
            return self._fail(state, job.error)
        try:
            placed = apply_result(context.scene, source, self.exported, job.report)
        except Exception as exc:  # a report this add-on cannot read, mostly: one line
            return self._fail(state, f"the result could not be applied: {type(exc).__name__}: {exc}")
        state.message = f"placed {', '.join(o.name for o in placed)}: {context.scene.ctp_result.summary}"
        self.report({"INFO"}, f"ctp: {state.message}")
        return {"FINISHED"}

    def _fail(self, state: bpy.types.PropertyGroup, message: str) -> set[str]:
        state.error = message
        self.report({"ERROR"}, f"ctp: {message}")
        return {"CANCELLED"}


class CTP_OT_cancel(bpy.types.Operator):
    """Cancel the running placement (DELETE /jobs/{id}); the scene stays as it is"""

    bl_idname = "ctp.cancel"
    bl_label = "Cancel"

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        return _running is not None

    def execute(self, context: bpy.types.Context) -> set[str]:
        _running.cancel()
        context.window_manager.ctp_job.message = "canceling"
        return {"FINISHED"}


class CTP_OT_keep(bpy.types.Operator):
    """Keep the alternative shown now and close the list"""

    bl_idname = "ctp.keep"
    bl_label = "Keep This One"
    bl_options = {"UNDO"}

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        return len(context.scene.ctp_result.alternatives) > 0

    def execute(self, context: bpy.types.Context) -> set[str]:
        context.scene.ctp_result.alternatives.clear()
        return {"FINISHED"}


CLASSES = (CTP_OT_place, CTP_OT_cancel, CTP_OT_keep)
