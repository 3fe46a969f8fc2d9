"""The chained target of ``POST /align`` (``target_job``): an earlier job's result scene, read back as its
objects, as the target of a new job that adds one object to it."""

from __future__ import annotations

from dataclasses import dataclass

from fastapi import Request
from fastapi.concurrency import run_in_threadpool

from ctp_core.errors import CtpError
from ctp_core.io import load_objects
from ctp_core.reading.cues import grounds
from service.deps import own_job
from service.errors import ApiError


@dataclass(frozen=True)
class ChainedTarget:
    """An earlier job's result scene as the target of a new one."""

    file: str
    data: bytes
    on: list[str]  # the objects the source relates to: one, or two ("between")
    faces: int


async def chained_target(request: Request, form, who: str, job_id: str, on: list[str],
                         prompt: str | None = None) -> ChainedTarget:
    """The result scene of the caller's succeeded job ``job_id``: 404 for another key's, 409 unfinished. The
    source relates to the objects ``on`` names (422 ``invalid_name`` for one the scene lacks); with fewer than
    two, to the two a "between" prompt names where it names two of the scene's objects; else the last placed."""
    if "target" in form:
        raise ApiError(400, "invalid_field", "give a target file or target_job, not both", field="target_job")
    record = await own_job(request, job_id.strip(), who)
    if record.status != "succeeded":
        raise ApiError(409, "job_not_ready", f"job {record.id} is {record.status}; only a succeeded job's "
                       "scene can be a target", field="target_job")
    state = request.app.state
    data = await run_in_threadpool(state.jobs.storage.get, record.id, "result.glb")
    if data is None:
        raise ApiError(404, "job_not_found", f"the results of job {record.id} have expired", field="target_job")
    file = f"{record.id}.glb"
    try:  # the service's own output, read in-process: only a corrupt store fails here
        scene = await run_in_threadpool(_load_objects, data, file, state.settings.mesh_limits)
    except CtpError as exc:
        raise ApiError(422, exc.code, exc.message, field="target_job") from None
    names = list(scene.geometry)  # load_objects: one geometry per node, named as it, in the file's order
    for name in on:
        if name not in names:
            raise ApiError(422, "invalid_name", f"on: job {record.id}'s scene has no object {name!r} "
                           f"(it has {', '.join(names)})", field="on")
    return ChainedTarget(file, data, grounds(prompt, on, names) or names[-1:],
                         sum(len(m.faces) for m in scene.geometry.values()))


def _load_objects(data: bytes, filename: str, limits):
    return load_objects(data, filename=filename, limits=limits, name=filename)
