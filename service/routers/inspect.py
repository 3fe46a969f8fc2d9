"""``POST /inspect``: one mesh read as a job would read it, before any job: its size, faces and the up the
service will use, so a wrong file, a model lying on its side or in the wrong units is seen at once (the page's
input previews), and a file a job would refuse is refused here with the same error codes."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from ctp_core import canonical
from service import forms
from service.deps import owner
from service.errors import documented

router = APIRouter()

INSPECT_BODY = {
    "required": True,
    "content": {"multipart/form-data": {"schema": {
        "type": "object",
        "additionalProperties": False,  # 400 unknown_field
        "required": ["mesh"],
        "properties": {"mesh": forms.mesh_field("one mesh, in any format `POST /align` takes")},
    }}},
}


class Inspection(BaseModel):
    """What a job would make of one mesh file (its file frame and units)."""

    file: str = Field(description="the file name as the service read it")
    faces: int = Field(description="triangles after loading (what CTP_MAX_FACES counts)")
    vertices: int = Field(description="vertices after loading")
    extents: list[float] = Field(description="axis-aligned size along the file's x, y, z, in the file's units")
    size: float = Field(description="the longest of the extents (file units)")
    up: list[float] = Field(description="the direction the service takes as up, a unit vector in the file frame "
                            "(the canonical pose's up: the file's +Y unless the model lies on a side or upside down)")
    turned: bool = Field(description="whether the service turns the model upright (up is not the file's +Y)")
    reason: str = Field(description="why that up, in words")


@router.post("/inspect", response_model=Inspection, openapi_extra={"requestBody": INSPECT_BODY},
             responses=documented(400, 401, 413, 415, 422, 503), summary="Read one mesh as a job would",
             description="Runs the bounded loader and the upright step on one mesh and says its size (file units), "
             "faces and the up the service will use (a job whose prompt hangs the source on this mesh keeps its "
             "file frame instead: what things hang on is fixed in place); queues nothing. A file a job would refuse "
             "is refused with the same codes (413 `mesh_file_too_large`, `mesh_too_large`; 415 "
             "`mesh_unknown_format`; 422 `mesh_unreadable` and the others), on the field `mesh`.")
async def inspect(request: Request, _who: str = Depends(owner)) -> Inspection:
    settings = request.app.state.settings
    form = await forms.read_form(request, {"mesh"}, max_files=1)
    upload = forms.file(form, "mesh")
    name = forms.file_name(upload, "mesh")
    data = await forms.read_limited(upload, settings.max_upload_bytes, "mesh", "mesh_file_too_large")
    mesh = await run_in_threadpool(forms.load_mesh, request.app.state.loader, data, name, settings.mesh_limits,
                                   "mesh")
    upright = await run_in_threadpool(canonical.upright_rotation, mesh)
    extents = [float(v) for v in mesh.extents]
    return Inspection(file=name, faces=len(mesh.faces), vertices=len(mesh.vertices), extents=extents,
                      size=max(extents), up=[round(float(v), 6) for v in upright.up], turned=upright.changed,
                      reason=upright.reason)
