"""The assembly API: ``POST /assemble`` builds a scene one object at a time as one job."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response
from fastapi.concurrency import run_in_threadpool

from ctp_core.assembly.describe import DESCRIPTION_MAX
from ctp_core.assembly.plan import PlanError, PlanStep, check_plan, plan_step
from ctp_core.config import AlignConfig
from ctp_core.errors import ConfigError
from ctp_core.guide.selection import asks_for_guide
from ctp_core.reading.names import NAME_MAX, default_name, ground_names
from service import forms, submit
from service.deps import owner
from service.errors import ApiError
from service.jobs import AssemblyAlso, AssemblyStep, JobRecord, now
from service.schemas import Accepted, build_config

router = APIRouter()

ASSEMBLE_FIELDS = {"base", "base_name", "source", "image", "plan", "description", "options", *forms.WEBHOOK_FIELDS}

ASSEMBLE_BODY = {
    "required": True,
    "content": {"multipart/form-data": {"schema": {
        "type": "object",
        "additionalProperties": False,  # 400 unknown_field
        "required": ["base", "source", "plan"],
        "dependentRequired": {"webhook_events": ["webhook"]},
        "properties": {
            "base": forms.mesh_field("the object that stays put (formats as POST /align's target); its file "
                                      "frame is the scene frame"),
            "base_name": {"type": "string", "maxLength": NAME_MAX,
                          "description": "what the base is (\"table\"); default: its file name"},
            "source": {"type": "array", "items": forms.mesh_field("a mesh to place"),
                       "description": "one part per source file, each with a distinct file name; the plan's "
                       "steps name them by `file`"},
            "image": {"type": "array", "items": forms.image_field("a reference picture"),
                      "description": "reference pictures of image-guided steps, named by a step's `image`"},
            "plan": {"type": "string", "minLength": 1, "contentMediaType": "application/json",
                     "description": "JSON list, one object per stage in placing order: `file` (a source part's "
                     "file name, required), `prompt` or `image` (an image part's file name), `name` (unique; "
                     "default the file stem), `on` (the placed object it relates to, or a list of two: "
                     "`[\"sofa\", \"armchair\"]` for \"a lamp between the sofa and the armchair\"; default the "
                     "last placed one, or the two placed objects a between prompt names), `also` (relations said "
                     "of it besides its own, judged with it and on the final scene: a list of `{prompt, on}`, e.g. "
                     "`{\"prompt\": \"the lamp to the right of the monitor\", \"on\": \"monitor\"}`), "
                     "`options` (AlignOptions of this stage, without preset and model)"},
            "description": {"type": "string", "minLength": 1, "maxLength": DESCRIPTION_MAX,
                            "pattern": forms.PROMPT_PATTERN,
                            "description": "the scene in one sentence, the job's label (`description` of GET "
                            "/jobs/{id}: the sentence a plan was read from by POST /plans/read, then edited); "
                            "default: the steps' prompts joined by \"; \""},
            "options": {"type": "string", "contentMediaType": "application/json",
                        "contentSchema": {"$ref": "#/components/schemas/JobOptions"},
                        "description": "JSON object of run options (JobOptions: AlignOptions for every stage, and "
                        "the job's queue)"},
            **forms.WEBHOOK_PROPERTIES,
        },
    }, "encoding": {"image": forms.IMAGE_ENCODING}}},
}


@router.post("/assemble", status_code=202, response_model=Accepted, openapi_extra={"requestBody": ASSEMBLE_BODY},
             responses=submit.RESPONSES, summary="Submit an assembly job",
             description="Build a scene one object at a time: stage k places the k-th step's source against "
             "everything placed before it (placed objects never move), as one job whose progress names the "
             "stage (`progress.stage.index`/`count`, `label` = its prompt). Its results are one GLB with every "
             "object as its own named node, a report of every stage and a preview of the whole scene. "
             "Refused before anything is queued: a malformed plan (400 `invalid_plan`), more stages than "
             "`CTP_MAX_STAGES` (413 `too_many_stages`), all meshes together over `CTP_MAX_SCENE_FACES` (413 "
             "`scene_too_large`), a bad reference between steps (422 `invalid_plan`), plus the mesh, image and "
             "option codes of POST /align. The job's time limit is `CTP_JOB_TIMEOUT_S` per stage. `webhook`, "
             "`Idempotency-Key` and `Prefer: wait` work as on POST /align.")
async def submit_assembly(request: Request, who: str = Depends(owner),
                          idempotency_key: str | None = submit.IDEMPOTENCY_KEY,
                          prefer: str | None = submit.PREFER) -> Response:
    settings = request.app.state.settings
    form = await forms.read_form(request, ASSEMBLE_FIELDS, max_files=1 + 2 * settings.max_stages)
    return await submit.accept(request, who, form, lambda job_id: _assembly_job(request, form, who, job_id),
                               idempotency_key=idempotency_key, prefer=prefer)


async def _assembly_job(request: Request, form, who: str, job_id: str) -> submit.Built:
    """The assembly a ``POST /assemble`` form asks for, checked: its record, uploads and every stage's config."""
    plan = _plan(forms.text(form, "plan"), request.app.state.settings.max_stages)
    base = forms.file(form, "base")
    base_file = forms.file_name(base, "base")
    said = forms.text(form, "description")
    description = None if said is None else forms.clean_prompt(said, "description", "description",
                                                                 DESCRIPTION_MAX)
    return await assembly_job(request, form, who, job_id, plan, base, forms.object_name(form, "base", base_file),
                              file_parts(form, "source"), description)


async def assembly_job(request: Request, form, who: str, job_id: str, plan: list[PlanStep], base,
                       base_name: str, sources: dict, description: str | None) -> submit.Built:
    """An assembly job checked (``POST /assemble``'s and ``POST /scenes``'s): the base part, the source parts by
    file name (one part may be read by several steps, the base's too), the form's options, images and webhooks;
    its record (labelled by ``description``, else its steps' prompts), uploads and every stage's config."""
    settings = request.app.state.settings
    options, queue = forms.job_options(form, settings.default_queue)
    # one guide for all stages (it is loaded once): a stage that asks for guidance asks it for the assembly
    guided = any(asks_for_guide({**options, **e.options}, e.image is not None) for e in plan)
    config = build_config(options, default_model=settings.model, allowed_models=settings.allowed_models,
                          image=guided)
    images = file_parts(form, "image")
    base_file = forms.file_name(base, "base")
    blobs = {"target": await forms.read_limited(base, settings.max_upload_bytes, "base", "mesh_file_too_large")}
    loader = request.app.state.loader
    faces = await run_in_threadpool(forms.check_mesh, loader, blobs["target"], base_file, settings.mesh_limits, "base")
    steps: list[AssemblyStep] = []
    configs: list[AlignConfig] = []  # every stage's own (the assembly's options, then the step's)
    meshes: dict[str, tuple[bytes, int]] = {}  # a part is read and checked once, however many steps use it
    pictures: dict[str, bytes] = {}
    for i, entry in enumerate(plan):
        where = f"plan.{i}"
        file = entry.file
        if file not in sources:
            raise ApiError(400, "invalid_plan", f"{where}: no source part has the file name {file!r}",
                           field=f"{where}.file")
        if file not in meshes and sources[file] is base:  # a copy of the base ("two tables with a lamp on each")
            meshes[file] = blobs["target"], faces
        elif file not in meshes:
            data = await forms.read_limited(sources[file], settings.max_upload_bytes, "source", "mesh_file_too_large")
            meshes[file] = data, await run_in_threadpool(forms.check_mesh, loader, data, file, settings.mesh_limits,
                                                         "source")
        blobs[f"source-{i}"], source_faces = meshes[file]
        faces += source_faces
        forms.check_scene_faces(faces, settings.max_scene_faces)
        if entry.image is not None:
            image = images.get(entry.image)
            if image is None:
                raise ApiError(400, "invalid_plan", f"{where}: no image part has the file name {entry.image!r}",
                               field=f"{where}.image")
            if entry.image not in pictures:
                data = await forms.read_limited(image, settings.max_image_bytes, "image", "image_too_large")
                await run_in_threadpool(forms.check_image, data, settings.max_image_pixels)
                pictures[entry.image] = data
            blobs[f"image-{i}"] = pictures[entry.image]
        try:
            step_config = build_config({**options, **entry.options}, default_model=settings.model,
                                       allowed_models=settings.allowed_models, image=guided)
        except ConfigError as exc:
            raise ApiError(422, exc.code, f"{where}: {exc.message}", field=f"{where}.{exc.field}") from None
        configs.append(step_config)
        prompt = None if entry.prompt is None else forms.clean_prompt(entry.prompt, f"{where}.prompt", where)
        steps.append(AssemblyStep(name=_name(entry.name, file, where), file=file, prompt=prompt,
                                  has_image=entry.image is not None, on=list(entry.on) or None,
                                  also=[AssemblyAlso(**a.to_dict()) for a in entry.also], config=step_config))
    unused = sorted(f for f, part in sources.items() if f not in meshes and part is not base)
    if unused:
        raise ApiError(400, "invalid_plan", f"source part {unused[0]!r} is not used by any step", field="source")
    try:
        check_plan(base_name, [(s.name, ground_names(s.on), s.prompt is not None or s.has_image or
                                s.config.loss.lambda_clip == 0) for s in steps])
    except ConfigError as exc:
        raise ApiError(422, "invalid_step", exc.message,
                       field=f"plan.{(exc.field or '').removeprefix('steps.')}") from None
    label = description or "; ".join(s.prompt or f"{s.name} (image-guided)" for s in steps)
    record = JobRecord(id=job_id, owner=who, created_at=now(), kind="assemble", prompt=None,  # per stage: steps
                       description=label,
                       has_image=any(s.has_image for s in steps), target_name=base_name, target_file=base_file,
                       source_name=steps[-1].name, source_file=steps[-1].file, steps=steps,
                       config=config, queue=queue, downloads=settings.downloads)
    return record, blobs, configs


def _plan(raw: str | None, max_stages: int) -> list[PlanStep]:
    """The plan field as its steps (their shape only; references and option values are checked later)."""
    if raw is None or not raw.strip():
        raise ApiError(400, "missing_field", "plan is required: a JSON list of steps", field="plan")
    plan = forms.strict_json(raw, "plan", "invalid_plan", max_chars=4 * forms.OPTIONS_MAX)
    if not isinstance(plan, list) or not plan:
        raise ApiError(400, "invalid_plan", "plan must be a non-empty JSON list of steps", field="plan")
    if len(plan) > max_stages:
        raise ApiError(413, "too_many_stages", f"the plan has {len(plan)} stages, over the limit of {max_stages}",
                       field="plan")
    try:
        return [plan_step(entry, f"plan.{i}", assembly_options="the options field") for i, entry in enumerate(plan)]
    except PlanError as exc:
        raise ApiError(400, "invalid_plan", exc.message, field=exc.field) from None


def file_parts(form, name: str) -> dict:
    """The file parts of a repeated field by file name (distinct names: the plan refers to them)."""
    parts = {}
    for value in form.getlist(name):
        if isinstance(value, str):
            raise ApiError(400, "invalid_field", f"{name} must be a file upload, not text", field=name)
        filename = forms.file_name(value, name) if value.filename else ""  # control characters: 422
        if not filename or filename in parts:
            raise ApiError(400, "invalid_field", f"every {name} part needs its own file name ({filename!r} "
                           "is missing or repeated)", field=name)
        parts[filename] = value
    return parts


def _name(name: str | None, file: str, where: str) -> str:
    return default_name(file, "object") if name is None else forms.clean_name(name, f"{where}.name")
