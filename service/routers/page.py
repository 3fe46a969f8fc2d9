"""The web page and the offline API docs: static files shipped inside the package, nothing from a CDN.

``/`` is the page (``service/static/index.html``; its script reads the JSON API like any client),
``/static`` its files and the vendored libraries (``service/static/vendor``, each with its licence),
``/page/config`` what the page needs to know of this deployment, ``/samples/...`` the built-in example
pairs (``ctp_core.io.examples``), ``/docs`` and ``/redoc`` the API docs on the vendored Swagger UI and ReDoc.
None of these routes is part of the API contract: they stay out of ``openapi.yaml``.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request, Response
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

from ctp_core.config import AlignConfig
from ctp_core.config.options import AlignOptions
from ctp_core.io import SUPPORTED_EXTENSIONS
from ctp_core.io.examples import EXAMPLES
from ctp_core.reading.names import NAME_MAX
from service.errors import ApiError
from service.forms import PROMPT_MAX

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"
VENDOR = "static/vendor"

router = APIRouter(include_in_schema=False)


def static_files() -> StaticFiles:
    """The app mounts this at ``/static`` (a router cannot carry a mount)."""
    return StaticFiles(directory=STATIC_DIR)


def _base(request: Request) -> str:
    """The API root as the browser sees it (behind a proxy that sets ``root_path``)."""
    return request.scope.get("root_path", "").rstrip("/")


@router.get("/", response_class=FileResponse)
def index() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})


@functools.cache
def _bounds() -> dict[str, dict[str, Any]]:
    """The page's options' JSON-schema bounds, read once from ``AlignOptions`` (the engine's own limits)."""
    properties = AlignOptions.model_json_schema()["properties"]
    return {option: _branch_bounds(properties[option]) for option in ("seed", "restarts")}


def _branch_bounds(schema: dict[str, Any]) -> dict[str, Any]:
    for branch in schema.get("anyOf", [schema]):
        if branch.get("type") not in (None, "null"):
            return {k: branch[k] for k in ("minimum", "maximum") if k in branch}
    return {}


@router.get("/page/config")
def page_config(request: Request) -> dict[str, Any]:
    """What the page adapts to: whether a key is needed, the presets, the option bounds, the samples."""
    settings = request.app.state.settings
    return {
        "auth": bool(request.app.state.key_digests),
        "presets": AlignConfig.preset_names(),
        "default_preset": "default",
        "bounds": _bounds(),
        "prompt_max": PROMPT_MAX,
        "name_max": NAME_MAX,
        "formats": list(SUPPORTED_EXTENSIONS),
        "max_upload_bytes": settings.max_upload_bytes,
        "max_image_bytes": settings.max_image_bytes,
        "samples": [{"name": s.name, "prompt": s.prompt, "target_name": s.target_name,
                     "source_name": s.source_name, "target_file": s.target_file, "source_file": s.source_file}
                    for s in EXAMPLES.values()],
    }


@functools.cache
def _sample_files(name: str) -> dict[str, bytes]:
    return EXAMPLES[name].files()


@router.get("/samples/{name}/{file}")
def sample_file(name: str, file: str) -> Response:
    """One GLB of a built-in pair, generated once per process."""
    data = _sample_files(name).get(file) if name in EXAMPLES else None
    if data is None:
        raise ApiError(404, "not_found", f"no sample file {name}/{file}; samples: {', '.join(EXAMPLES)}")
    return Response(data, media_type="model/gltf-binary", headers={"Cache-Control": "max-age=3600"})


@router.get("/docs", response_class=HTMLResponse)
def swagger_ui(request: Request) -> HTMLResponse:
    base = _base(request)
    return get_swagger_ui_html(
        openapi_url=base + request.app.openapi_url, title=f"{request.app.title} - API docs",
        swagger_js_url=f"{base}/{VENDOR}/swagger-ui/swagger-ui-bundle.js",
        swagger_css_url=f"{base}/{VENDOR}/swagger-ui/swagger-ui.css",
        swagger_favicon_url=f"{base}/{VENDOR}/swagger-ui/favicon-32x32.png")


@router.get("/redoc", response_class=HTMLResponse)
def redoc(request: Request) -> HTMLResponse:
    base = _base(request)
    return get_redoc_html(
        openapi_url=base + request.app.openapi_url, title=f"{request.app.title} - API reference",
        redoc_js_url=f"{base}/{VENDOR}/redoc/redoc.standalone.js",
        redoc_favicon_url=f"{base}/{VENDOR}/swagger-ui/favicon-32x32.png", with_google_fonts=False)
