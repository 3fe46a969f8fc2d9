"""``POST /inspect``: one mesh read as a job would read it, before any job: its size, faces and the up the
service will use, so a wrong file, a model lying on its side or in the wrong units is seen at once (the page's
input previews), and a file a job would refuse is refused here with the same error codes."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from ctp_core import orientation
from ctp_core.errors import ConfigError
from service import forms
from service.deps import owner
from service.errors import ApiError, documented

router = APIRouter()

INSPECT_BODY = {
    "required": True,
    "content": {"multipart/form-data": {"schema": {
        "type": "object",
        "additionalProperties": False,  # 400 unknown_field
        "required": ["mesh"],
        "properties": {
            "mesh": forms.mesh_field("one mesh, in any format `POST /align` takes"),
            **{name: {"type": "string", "enum": list(orientation.DIRECTIONS), "default": "file",
                      "description": f"where the object's {name} comes from, as the job option `target_{name}` "
                      f"(or `source_{name}`) says it: {what}"}
               for name, what in (("up", "file (the format's convention: +Y for glTF; OBJ, STL, PLY Y-up unless it "
                                          "stands only with +Z up), auto (geometric guess), or an axis of the file"),
                                  ("front", "file (+Z for glTF), auto (geometric guess), or an axis of the file at "
                                            "right angles to the up"))},
        },
    }}},
}


class Inspection(BaseModel):
    """What a job would make of one mesh file (its file frame and units)."""

    file: str = Field(description="the file name as the service read it")
    faces: int = Field(description="triangles after loading (what CTP_MAX_FACES counts)")
    vertices: int = Field(description="vertices after loading")
    extents: list[float] = Field(description="axis-aligned size along the file's x, y, z, in the file's units")
    size: float = Field(description="the longest of the extents (file units)")
    up: list[float] = Field(description="the direction a job takes as up, a unit vector in the file frame (the "
                            "file's convention unless `up` says otherwise: docs/engine.md, frames)")
    turned: bool = Field(description="whether the job turns the model upright (up is not the file's +Y)")
    reason: str = Field(description="why that up, in words")
    front: list[float] = Field(description="the direction a job takes as the object's front, a unit vector in the "
                               "file frame at right angles to the up")
    front_trusted: bool = Field(description="whether a convention or the user gave the front (false: a guess, or "
                                "a symmetric object: directional relations then use the viewer's frame)")
    front_reason: str = Field(description="why that front, in words")


@router.post("/inspect", response_model=Inspection, openapi_extra={"requestBody": INSPECT_BODY},
             responses=documented(400, 401, 413, 415, 422, 503), summary="Read one mesh as a job would",
             description="Runs the bounded loader and the frame step on one mesh and says its size (file units), "
             "faces and the up and front a job will use with the same `up` and `front` options (the page shows "
             "them as arrows and lets the user flip them); queues nothing. A file a job would refuse "
             "is refused with the same codes (413 `mesh_file_too_large`, `mesh_too_large`; 415 "
             "`mesh_unknown_format`; 422 `mesh_unreadable` and the others), on the field `mesh`.")
async def inspect(request: Request, _who: str = Depends(owner)) -> Inspection:
    settings = request.app.state.settings
    form = await forms.read_form(request, {"mesh", "up", "front"}, max_files=1)
    try:
        axes = orientation.Axes(*(forms.text(form, name) or "file" for name in ("up", "front")))
    except ConfigError as exc:
        raise ApiError(422, "invalid_option", str(exc), field=exc.field) from None  # as a job's up and front
    upload = forms.file(form, "mesh")
    name = forms.file_name(upload, "mesh")
    data = await forms.read_limited(upload, settings.max_upload_bytes, "mesh", "mesh_file_too_large")
    mesh = await run_in_threadpool(forms.load_mesh, request.app.state.loader, data, name, settings.mesh_limits,
                                   "mesh")
    upright = await run_in_threadpool(orientation.orient, mesh, axes)
    extents = [float(v) for v in mesh.extents]
    frame = orientation.to_dict(upright)
    return Inspection(file=name, faces=len(mesh.faces), vertices=len(mesh.vertices), extents=extents,
                      size=max(extents), turned=upright.changed, **{k: v for k, v in frame.items()})
