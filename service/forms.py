"""The ``POST /align`` form (its documented body) and the checks every submit route runs before anything
is queued (``POST /assemble`` reads its form with them too).

Everything a worker would refuse is refused here first: meshes are parsed by the bounded loader
(``ctp_core.io.loader.MeshLoader``) under the service limits, the image is decoded with
``ctp_core.io.load_image``, text fields are bounded.
"""

from __future__ import annotations

import json
import logging
import math
import re
import time
from contextlib import contextmanager
from pathlib import PurePath
from typing import Any

from fastapi import Request
from starlette.datastructures import UploadFile

from ctp_core.assembly.plan import MAX_GROUNDS
from ctp_core.errors import CtpError, ImageError, MeshError
from ctp_core.io import SUPPORTED_EXTENSIONS, MeshLimits, load_image
from ctp_core.io.loader import LoaderUnavailable, MeshLoader
from ctp_core.reading.names import NAME_MAX, default_name
from service.errors import ApiError
from service.settings import QUEUE_NAME, QUEUE_RULE
from service.webhooks import DEFAULT_EVENTS, EVENTS, URL_MAX

log = logging.getLogger("ctp.service")

PROMPT_MAX = 500
OPTIONS_MAX = 16 * 1024  # characters of the options JSON
OPTIONS_DEPTH = 8  # nesting of the options JSON (AlignOptions is flat)
INT_MAX = 2**63 - 1  # JSON integers must fit in 64 bits
# C0 control characters; a prompt may hold tab, newline and carriage return, a name none of them.
_PROMPT_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")
_NAME_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
# What ``clean_name`` accepts, as the contract states it: a character that is not a space, no control characters.
NAME_PATTERN = r"^[^\x00-\x1f\x7f]*[^\s\x00-\x1f\x7f][^\x00-\x1f\x7f]*$"
NAME_SCHEMA = {"type": "string", "minLength": 1, "maxLength": NAME_MAX, "pattern": NAME_PATTERN}
# What ``clean_prompt`` accepts: a character that is not a space, no control characters but tab, newline, return.
PROMPT_PATTERN = r"^[^\x00-\x08\x0b\x0c\x0e-\x1f\x7f]*[^\s\x00-\x1f\x7f][^\x00-\x08\x0b\x0c\x0e-\x1f\x7f]*$"
LIST_FIELDS = ("one part per item (`on=sofa`, `on=armchair`) or one part holding a JSON list "
               "(`on=[\"sofa\", \"armchair\"]`; a single part starting with `[` is read so); 400 `invalid_field` "
               "for a malformed list or a wrong count")
WEBHOOK_FIELDS = {"webhook", "webhook_events"}  # both submit routes (service.submit)
FORM_FIELDS = {"target", "source", "prompt", "image", "options", "target_name", "source_name",
               "target_job", "on", *WEBHOOK_FIELDS}

# MeshError codes that are not 422.
_MESH_STATUS = {"mesh_file_too_large": 413, "mesh_too_large": 413, "mesh_too_complex": 413,
                "mesh_unknown_format": 415}


def file_field(description: str) -> dict[str, Any]:
    """A file part of a documented multipart body."""
    return {"type": "string", "format": "binary", "description": description}


def mesh_field(description: str) -> dict[str, Any]:
    """A mesh file part: its format is its file name's extension, one of ``x-extensions`` (415
    ``mesh_unknown_format`` for another)."""
    return {**file_field(f"{description}; the file name's extension gives the format: "
                         f"{', '.join(SUPPORTED_EXTENSIONS)} (415 `mesh_unknown_format` otherwise)"),
            "x-extensions": list(SUPPORTED_EXTENSIONS)}


def image_field(description: str) -> dict[str, Any]:
    """A picture file part, read by its content (``IMAGE_ENCODING``; 422 ``invalid_image`` otherwise)."""
    return file_field(f"{description}; PNG or JPEG, told by its content (422 `invalid_image` otherwise)")


IMAGE_ENCODING = {"contentType": "image/png, image/jpeg"}  # a multipart body's ``encoding`` of its picture parts


WEBHOOK_PROPERTIES = {
    "webhook": {"type": "string", "format": "uri", "maxLength": URL_MAX, "description": "http(s) URL to POST "
                "the job's events to, signed as Standard Webhooks does (docs/service.md, Webhooks); its host must "
                "resolve to public addresses (422 `webhook_url_refused` otherwise, unless the service allows "
                "private ones); 422 `webhooks_disabled` when the service has no signing secret"},
    "webhook_events": {"type": "string", "default": ",".join(DEFAULT_EVENTS), "description": "with `webhook`: "
                       f"comma-separated events to send, of {', '.join(EVENTS)} (progress at most once a second; "
                       "completed: succeeded, failed or canceled)"},
}

ALIGN_BODY = {
    "required": True,
    "content": {"multipart/form-data": {"schema": {
        "type": "object",
        "additionalProperties": False,  # 400 unknown_field
        "required": ["source"],
        # a prompt or a picture guides it (400 missing_field without both); the target is a file or an earlier
        # job's scene (400 missing_field / invalid_field without one or with both)
        "allOf": [{"anyOf": [{"required": ["prompt"]}, {"required": ["image"]}]},
                  {"oneOf": [{"required": ["target"]}, {"required": ["target_job"]}]}],
        "dependentRequired": {"on": ["target_job"], "webhook_events": ["webhook"]},
        "properties": {
            "target": mesh_field("the mesh that stays put (GLB, glTF with embedded buffers, OBJ, OBJ+MTL in a "
                                  ".zip, PLY, STL); required unless `target_job` is given"),
            "target_job": {"type": "string", "description": "instead of `target` (not with it): the id of one of "
                           "your succeeded jobs, whose result scene becomes the target, read back as its separate "
                           "objects (404 for an unknown job or another key's, 409 if it has not succeeded)"},
            "on": {"type": "array", "items": NAME_SCHEMA, "minItems": 1, "maxItems": MAX_GROUNDS, "uniqueItems": True,
                   "description": "with `target_job`: the object of that scene the source relates to (soft-ICP "
                   "attaches to it), or two objects (\"a lamp between the sofa and the armchair\"): "
                   f"{LIST_FIELDS}; default the last placed one, or the two placed objects a between prompt names; "
                   "422 `invalid_name` for a name the scene does not have"},
            "source": mesh_field("the mesh to place, same formats"),
            "prompt": {"type": "string", "minLength": 1, "maxLength": PROMPT_MAX, "pattern": PROMPT_PATTERN,
                       "description": "what the arrangement should look like; required unless `image` is given"},
            "image": image_field("reference picture for image-guided alignment instead of the text"),
            "options": {"type": "string", "contentMediaType": "application/json",
                        "contentSchema": {"$ref": "#/components/schemas/JobOptions"},
                        "description": "JSON object of run options (JobOptions: AlignOptions and queue)"},
            "target_name": {**NAME_SCHEMA, "description": "what the target is (\"sundae\"), for the scene priors; "
                            "default: its file name"},
            "source_name": {**NAME_SCHEMA, "description": "what the source is (\"cherry\"); default: its file name"},
            **WEBHOOK_PROPERTIES,
        },
    }, "encoding": {"image": IMAGE_ENCODING}}},
}


async def read_form(request: Request, fields: set[str] = FORM_FIELDS, max_files: int = 3):
    if not request.headers.get("content-type", "").startswith("multipart/form-data"):
        raise ApiError(400, "invalid_request", f"send multipart/form-data (fields {', '.join(sorted(fields))})")
    try:
        form = await request.form(max_files=max_files, max_fields=10 + max_files)  # a list field: a part per file
    except ApiError:
        raise
    except Exception as exc:  # python-multipart and Starlette raise several types for a broken body
        raise ApiError(400, "invalid_request", f"malformed multipart body: {exc}") from None
    for key in form:
        if key not in fields:
            raise ApiError(400, "unknown_field", f"unknown form field {key!r}; known: {', '.join(sorted(fields))}",
                           field=key)
    return form


def text(form, name: str) -> str | None:
    return text_value(form.get(name), name)


def text_value(value, name: str) -> str | None:
    """One text part of field ``name`` (None: absent): 400 ``invalid_field`` for a file or text not UTF-8."""
    if isinstance(value, UploadFile):
        raise ApiError(400, "invalid_field", f"{name} must be a text field, not a file", field=name)
    if value is not None:
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:  # lone surrogates: the body was not UTF-8
            raise ApiError(400, "invalid_field", f"{name} is not valid UTF-8 text", field=name) from None
    return value


def text_list(form, name: str) -> list[str] | None:
    """A list field (``LIST_FIELDS``): its parts, or the JSON list of strings its one part holds (None: absent);
    400 ``invalid_field`` for a malformed list."""
    parts = [text_value(value, name) for value in form.getlist(name)]
    if len(parts) != 1 or not (parts[0] or "").lstrip().startswith("["):
        return [part for part in parts if part is not None] or None
    items = strict_json(parts[0] or "", name, "invalid_field")
    if not isinstance(items, list) or not all(isinstance(item, str) for item in items):
        raise ApiError(400, "invalid_field", f"{name} must be a JSON list of strings, or one part per item",
                       field=name)
    return items


def grounds(form) -> list[str]:
    """The ``on`` list (``text_list``): 0 to ``MAX_GROUNDS`` distinct names; 400 ``invalid_field`` otherwise."""
    names = text_list(form, "on") or []
    if len(names) > MAX_GROUNDS or len(set(names)) < len(names):
        raise ApiError(400, "invalid_field", f"on names one object or {MAX_GROUNDS} different ones "
                       f"(got {len(names)})", field="on")
    return names


def file(form, name: str) -> UploadFile:
    value = form.get(name)
    if value is None:
        raise ApiError(400, "missing_field", f"{name} is required (a file)", field=name)
    if not isinstance(value, UploadFile):
        raise ApiError(400, "invalid_field", f"{name} must be a file upload, not text", field=name)
    return value


def prompt_and_image(form) -> tuple[str | None, UploadFile | None]:
    prompt = text(form, "prompt")
    image = file(form, "image") if "image" in form else None
    if prompt is None and image is None:
        raise ApiError(400, "missing_field", "give a prompt (or an image for image-guided alignment)", field="prompt")
    return (clean_prompt(prompt) if prompt is not None else None), image


def clean_prompt(prompt: str, field: str = "prompt", where: str = "", limit: int = PROMPT_MAX) -> str:
    """A prompt as the engine gets it (stripped); 422 ``invalid_prompt`` when empty, longer than ``limit`` or
    holding control characters. ``where`` prefixes the message (an assembly step: ``plan.1``)."""
    prefix = f"{where}: " if where else ""
    if not 1 <= len(prompt.strip()) <= limit:
        raise ApiError(422, "invalid_prompt", f"{prefix}the prompt must have 1 to {limit} characters",
                       field=field)
    if _PROMPT_CONTROL.search(prompt):
        raise ApiError(422, "invalid_prompt", f"{prefix}the prompt holds control characters (only tab, newline "
                       "and carriage return are allowed)", field=field)
    return prompt.strip()


def options(form) -> dict[str, Any]:
    raw = text(form, "options")
    if raw is None or not raw.strip():
        return {}
    parsed = strict_json(raw, "options", "invalid_options")
    if not isinstance(parsed, dict):
        raise ApiError(400, "invalid_options", "options must be a JSON object", field="options")
    return parsed


def job_options(form, default_queue: str) -> tuple[dict[str, Any], str]:
    """The job's options for the engine (AlignOptions), and the named queue it asks for (the service's own option,
    ``queue``; default ``default_queue``): 422 ``invalid_option`` for a name no queue can have."""
    engine = options(form)
    queue = engine.pop("queue", default_queue)
    if not isinstance(queue, str) or not re.match(QUEUE_NAME, queue):
        raise ApiError(422, "invalid_option", f"queue must be a queue name: {QUEUE_RULE}", field="options.queue")
    return engine, queue


def copies_options(options: dict[str, Any]) -> tuple[int | None, str]:
    """Takes the alignment's ``count`` and ``arrangement`` (the service's own options,
    ``ctp_core.assembly.copies``) out of
    ``options``; the values are checked by ``priors.counts.choose``."""
    return options.pop("count", None), options.pop("arrangement", None) or "auto"


def strict_json(raw: str, field: str, code: str, max_chars: int = OPTIONS_MAX) -> Any:
    """JSON a client sent, bounded before parsing (size, nesting: no parser recursion is deep) and strict in
    what it holds (integers in 64 bits, finite numbers); 400 ``code`` otherwise."""
    if len(raw) > max_chars:
        raise ApiError(400, code, f"{field} is over {max_chars} characters", field=field)
    if _depth(raw) > OPTIONS_DEPTH:
        raise ApiError(400, code, f"{field} nests deeper than {OPTIONS_DEPTH} levels", field=field)
    try:
        return json.loads(raw, parse_int=_int64, parse_float=_finite, parse_constant=_no_constant)
    except ValueError as exc:  # JSONDecodeError, and the hooks' refusals
        raise ApiError(400, code, f"{field} is not valid JSON: {exc}", field=field) from None


def _depth(raw: str) -> int:
    """Deepest bracket nesting, strings skipped: checked before parsing, so no parser recursion is deep."""
    depth = deepest = 0
    in_string = escaped = False
    for char in raw:
        if in_string:
            escaped, in_string = (False, True) if escaped else (char == "\\", char != '"')
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def _int64(literal: str) -> int:
    if len(literal) > 20 or abs(value := int(literal)) > INT_MAX:
        raise ValueError(f"integer {literal[:24]}... does not fit in 64 bits" if len(literal) > 24
                         else f"integer {literal} does not fit in 64 bits")
    return value


def _finite(literal: str) -> float:
    value = float(literal)
    if not math.isfinite(value):
        raise ValueError(f"number {literal[:24]} is out of range")
    return value


def _no_constant(literal: str):
    raise ValueError(f"{literal} is not a JSON number")


def object_name(form, role: str, filename: str) -> str:
    name = text(form, f"{role}_name")
    return default_name(filename, role) if name is None else clean_name(name, f"{role}_name")


def clean_name(name: str, field: str) -> str:
    """An object's name (stripped); 422 ``invalid_name`` when empty, too long or holding control characters."""
    if not 1 <= len(name.strip()) <= NAME_MAX:
        raise ApiError(422, "invalid_name", f"{field} must have 1 to {NAME_MAX} characters", field=field)
    if _NAME_CONTROL.search(name):
        raise ApiError(422, "invalid_name", f"{field} holds control characters", field=field)
    return name.strip()


def file_name(upload: UploadFile, role: str) -> str:
    """The upload's base name (its extension names the format); control characters are refused."""
    name = PurePath(upload.filename or role).name
    if _NAME_CONTROL.search(name) or len(name) > 255:
        raise ApiError(422, "invalid_name", f"the {role} file name holds control characters or is over 255 "
                       "characters", field=role)
    return name


async def read_limited(upload: UploadFile, max_bytes: int, field: str, code: str) -> bytes:
    if upload.size is not None and upload.size > max_bytes:
        raise ApiError(413, code, f"{field} is over the {max_bytes}-byte limit", field=field)
    return await upload.read()


@contextmanager
def _mesh_errors(role: str):
    """The bounded loader's refusals as the API's errors, on the form field ``role``."""
    try:
        yield
    except LoaderUnavailable as exc:
        raise ApiError(503, exc.code, exc.message, field=role) from None
    except MeshError as exc:
        raise ApiError(_MESH_STATUS.get(exc.code, 422), exc.code, exc.message, field=role) from None
    except CtpError as exc:
        raise ApiError(422, exc.code, exc.message, field=role) from None


def check_mesh(loader: MeshLoader, data: bytes, filename: str, limits: MeshLimits, role: str) -> int:
    """Parse exactly as the worker will (in a loading process, bounded), so a queued job never fails on
    its input; returns its face count."""
    started = time.perf_counter()
    with _mesh_errors(role):
        faces = loader.check(data, filename, limits)
    log.debug("mesh checked", extra={"duration_ms": round(1000 * (time.perf_counter() - started))})
    return faces


def load_mesh(loader: MeshLoader, data: bytes, filename: str, limits: MeshLimits, role: str):
    """``check_mesh``'s parse, returning the ``trimesh.Trimesh`` (``POST /inspect`` reads it)."""
    with _mesh_errors(role):
        return loader.load(data, filename=filename, limits=limits, name=filename)


def check_image(data: bytes, max_pixels: int) -> None:
    """Decode exactly as the worker will (``ctp_core.io.load_image``)."""
    try:
        load_image(data, max_pixels=max_pixels)
    except ImageError as exc:
        raise ApiError(413 if exc.code == "image_too_large" else 422, exc.code, exc.message, field="image") from None


def check_scene_faces(faces: int, limit: int) -> None:
    """All meshes of one job together (``check_mesh``'s counts summed) against ``CTP_MAX_SCENE_FACES``."""
    if faces > limit:
        raise ApiError(413, "scene_too_large", f"the job's meshes have {faces:,} faces together, over the limit "
                       f"of {limit:,}", field="source")
