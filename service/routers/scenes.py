"""A scene from one sentence over HTTP: ``POST /plans/read`` reads a description into a plan (no job, so a client
shows the plan and lets a person correct it), ``POST /scenes`` reads it and places it as an assembly job
(``ctp_core.assembly.describe``, then ``POST /assemble``'s checks and job)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Request, Response
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from ctp_core.assembly.describe import DESCRIPTION_MAX, DescriptionError, ScenePlan
from ctp_core.assembly.plan import plan_step
from ctp_core.assembly.readers import get_reader
from ctp_core.reading.names import NAME_MAX, default_name
from service import forms, submit
from service.deps import owner
from service.errors import ApiError, documented
from service.routers.assemble import assembly_job, file_parts
from service.schemas import Accepted

router = APIRouter()

SCENE_FIELDS = {"object", "names", "prompt", "options", *forms.WEBHOOK_FIELDS}

SCENE_BODY = {
    "required": True,
    "content": {"multipart/form-data": {"schema": {
        "type": "object",
        "additionalProperties": False,  # 400 unknown_field
        "required": ["object", "prompt"],
        "dependentRequired": {"webhook_events": ["webhook"]},
        "properties": {
            "object": {"type": "array", "items": forms.mesh_field("one object of the scene"),
                       "description": "one part per object, each with a distinct file name, in the order of "
                       "`names`"},
            "names": {"type": "array", "items": forms.NAME_SCHEMA, "minItems": 1,
                      "description": "what each object is, one name per `object` part in their order: "
                      f"{forms.LIST_FIELDS.replace('on=', 'names=')} (default: their file names: `paint_tin.glb` is "
                      "\"paint tin\")"},
            "prompt": {"type": "string", "minLength": 1, "maxLength": DESCRIPTION_MAX,
                       "description": "the scene in one sentence (\"a piano with its stool in front of it and a "
                       "metronome on top\")"},
            "options": {"type": "string", "contentMediaType": "application/json",
                        "contentSchema": {"$ref": "#/components/schemas/JobOptions"},
                        "description": "JSON object of run options (JobOptions: AlignOptions for every stage, and "
                        "the job's queue)"},
            **forms.WEBHOOK_PROPERTIES,
        },
    }}},
}


class PlanRequest(BaseModel):
    """A description and the names of the objects it may name."""

    prompt: str = Field(min_length=1, max_length=DESCRIPTION_MAX, description="the scene in one sentence")
    names: list[Annotated[str, Field(min_length=1, max_length=NAME_MAX, pattern=forms.NAME_PATTERN)]] = Field(
        min_length=2, max_length=64, description="what each object is (an upload's name, or its file name), in "
        f"upload order; 1 to {NAME_MAX} characters, one not a space, no control characters")


class AlsoSaid(BaseModel):
    """A relation said of a step's object besides the one that places it ("the lamp on the desk to its right":
    right of the monitor)."""

    relation: str = Field(description="the relation the reader reads of `prompt`")
    on: list[str] = Field(description="the placed objects it relates to")
    prompt: str = Field(description="the relation in words, by name")


class PlannedStep(BaseModel):
    """One step of a read plan."""

    name: str = Field(description="the node it places (a copy: `<name>_k`)")
    upload: int = Field(description="the object (index into `names`) it places")
    prompt: str = Field(description="what the step's run reads and is guided by")
    on: list[str] = Field(description="the placed objects it relates to (two: \"between\")")
    relation: str = Field(description="the relation the reader reads of `prompt` (as `ctp priors` reads it)")
    said: str = Field(description="the clause it comes from; empty where the description does not place it")
    floor: bool = Field(description="on the floor beside the base: said so, or not placed by the description")
    support: str = Field(description="what the object stands on: the ground of an on/in relation; beside, between "
                         "or in front of objects standing on the same thing, that thing; else `floor`")
    also: list[AlsoSaid] = Field(description="the other relations the description says of the object")
    warnings: list[str] = Field(description="what was assumed about this step (an object not placed by the "
                                "description, a part of a ground not told apart)")


class ReadPlan(BaseModel):
    """A description read into a plan: the base stays put; the steps in placing order."""

    description: str = Field(description="the description as read (the request's `prompt`)")
    base: str = Field(description="the object that stays put (its file frame is the scene frame)")
    base_upload: int = Field(description="its index into `names`")
    steps: list[PlannedStep] = Field(description="the objects placed, in placing order: every ground before its "
                                     "figures")
    base_support: str = Field(description="what the base stands on: `floor`")
    warnings: list[str] = Field(description="what was assumed: every step's warnings, names matched by order, a "
                                "reader that fell back to the rules")
    reader: str = Field(description="who read it: `rules`, `openai`, or `rules (fallback: why)`")


@router.post("/plans/read", response_model=ReadPlan, responses=documented(400, 401, 422, 503),
             summary="Read a description into a plan",
             description="The plan `POST /scenes` would place, read from `prompt` over the objects called `names`, "
             "without a job: each object a step (its relation and grounds, what it stands on, the other relations "
             "said of it, its warnings), the base the object that supports others, every ground placed before its "
             "figures, copies for a count. Read by the rules unless the service sets `CTP_PLAN_READER=openai` (an "
             "OpenAI-compatible endpoint, the rules on any failure: `reader` says which). 422 with the reader's code "
             "where the description cannot be read: `unknown_object` (it names an object no name matches), "
             "`placement_cycle`, `placed_twice`, `nothing_placed`, `unclear_clause`, `too_few_objects`, "
             "`empty_description`, `invalid_description`.")
async def read_plan(body: PlanRequest, _who: str = Depends(owner)) -> ReadPlan:
    names = [forms.clean_name(name, f"names.{i}") for i, name in enumerate(body.names)]
    return ReadPlan(**(await _read(body.prompt, names)).to_dict())


@router.post("/scenes", status_code=202, response_model=Accepted, openapi_extra={"requestBody": SCENE_BODY},
             responses=submit.RESPONSES, summary="Submit a scene described in one sentence",
             description="Reads `prompt` into a plan over the `object` parts (as `POST /plans/read` does; its "
             "errors are 422 with the same codes, field `prompt` or `names`) and places it as an assembly job "
             "(`POST /assemble`'s checks, progress per stage: `progress.stage.index`/`count`, `label` = the step's "
             "prompt; results: one GLB node per object, a report with every relation judged again on the final "
             "scene under `whole`). An object part the plan does not use is impossible: every part is named or "
             "put beside the base (a warning of `POST /plans/read`). `webhook`, `Idempotency-Key` and "
             "`Prefer: wait` work as on POST /align.")
async def submit_scene(request: Request, who: str = Depends(owner),
                       idempotency_key: str | None = submit.IDEMPOTENCY_KEY,
                       prefer: str | None = submit.PREFER) -> Response:
    settings = request.app.state.settings
    form = await forms.read_form(request, SCENE_FIELDS, max_files=settings.max_stages + 1)
    return await submit.accept(request, who, form, lambda job_id: _scene_job(request, form, who, job_id),
                               idempotency_key=idempotency_key, prefer=prefer)


async def _scene_job(request: Request, form, who: str, job_id: str) -> submit.Built:
    """The assembly a ``POST /scenes`` form describes: the description read over the parts, then an assembly."""
    parts = file_parts(form, "object")
    files = list(parts)
    prompt = forms.text(form, "prompt")
    if prompt is None or not prompt.strip():
        raise ApiError(400, "missing_field", "prompt is required: the scene in one sentence", field="prompt")
    plan = await _read(prompt, _names(form, files))  # each step's prompt is checked as POST /assemble checks it
    if len(plan.steps) > request.app.state.settings.max_stages:
        raise ApiError(413, "too_many_stages", f"the plan has {len(plan.steps)} stages, over the limit of "
                       f"{request.app.state.settings.max_stages}", field="prompt")
    written = plan.assembly_plan(files)
    steps = [plan_step(entry, f"plan.{i}", assembly_options="the options field")
             for i, entry in enumerate(written["steps"])]
    return await assembly_job(request, form, who, job_id, steps, parts[written["base"]], plan.base, parts,
                              prompt.strip())


def _names(form, files: list[str]) -> list[str]:
    """The objects' names: the ``names`` list field (``forms.text_list``), one per part, else the parts' file
    names; 400 ``invalid_field`` for a wrong count."""
    names = forms.text_list(form, "names")
    if names is None:
        return [default_name(file, "object") for file in files]
    if len(names) != len(files):
        raise ApiError(400, "invalid_field", f"names has {len(names)} names for {len(files)} object parts: one "
                       "per part", field="names")
    return [forms.clean_name(name, f"names.{i}") for i, name in enumerate(names)]


async def _read(prompt: str, names: list[str]) -> ScenePlan:
    """The plan reader's plan (``readers.get_reader``: the rules unless ``CTP_PLAN_READER`` says otherwise; a model's
    endpoint is asked off the event loop), its refusals as 422 with the reader's code."""
    try:
        return await run_in_threadpool(get_reader().read, prompt, names)
    except DescriptionError as exc:
        raise ApiError(422, exc.code, exc.message, field=exc.field) from None
