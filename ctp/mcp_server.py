"""The Model Context Protocol server of ``ctp mcp``: ctp's placements as tools a language-model agent calls.

Built on the official SDK's ``MCPServer``; a thin adapter over the HTTP service through ``service.client``: a tool
reads the files the agent names (paths on this machine), uploads them, follows the job (progress notifications
while it runs), downloads the result GLB and the report under ``results`` and answers with the transform, the
verdict in words, the contact and the alternatives. The service does the work and says what is wrong; a refusal
is a tool error (``isError``) carrying the service's code and message, never a traceback. No engine logic here.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import anyio
import anyio.from_thread
import anyio.to_thread
import httpx
from mcp.server.mcpserver import Context, MCPServer
from mcp.types import CallToolResult, TextContent
from pydantic import Field

from ctp_core.config import PRESETS, Direction
from ctp_core.geometry.frames import z_up
from ctp_core.reading.counts import ARRANGEMENTS
from ctp_core.reading.names import default_name
from service.client import Client, ServiceError

INSTRUCTIONS = """\
ctp places one 3D object relative to another from a sentence ("a cup on the table") and judges the answer with the
geometry: contact, support, penetration and whether the sentence's relation holds. Use it instead of guessing
coordinates. Meshes are files on the machine this server runs on (GLB, glTF, OBJ, PLY, STL or a zip of one). A
transform is a row-major 4x4 that moves the placed object's file frame into the reference object's file frame:
`matrix` in glTF's axes (+Y up), `matrix_z_up` in Blender's (+Z up). `read_plan` checks a sentence for free; `place`
and `compose` run a job (a few seconds with preset "test" or "fast", tens with "default" on a small CPU service,
minutes with "descent", hours with "paper"); `job_status` and `cancel` follow or stop one."""

Preset = Literal[tuple(PRESETS)]  # type: ignore[valid-type]
Arrangement = Literal[("auto", *ARRANGEMENTS)]  # type: ignore[valid-type]
Path_ = Annotated[str, Field(description="path of a mesh file on the machine the ctp MCP server runs on (absolute "
                             "or relative to its working directory): .glb, .gltf, .obj, .ply, .stl or .zip")]
PresetArg = Annotated[Preset | None, Field(description="run budget: test (seconds, for trying things), fast "
                                           "(seconds), default (a search, then refinement; the service's "
                                           "default), descent (minutes), paper (hours)")]
SeedArg = Annotated[int | None, Field(ge=0, le=2**32 - 1, description="random seed (the same seed and inputs give "
                                      "the same answer)")]
OptionsArg = Annotated[dict[str, Any] | None, Field(description="further job options as the service names them "
                                                    "(JobOptions in its openapi.yaml: scale, restarts, steps, "
                                                    "target_up, source_front, ...); unknown keys are refused")]
WaitArg = Annotated[bool, Field(description="true: follow the job to its end (progress notifications while it "
                                "runs) and answer with the result; false: answer at once with the job's id for "
                                "job_status")]
TimeoutArg = Annotated[float, Field(gt=0, le=3600, description="with wait: seconds to follow the job before "
                                    "answering with its status (it goes on running; job_status follows it again)")]
JOB_FIELDS = ("status", "guide", "guide_why", "error")


class ToolFailure(Exception):
    """A refusal of this server's own (a file it cannot read, no service): answered like the service's errors."""

    def __init__(self, code: str, message: str, field: str | None = None):
        super().__init__(f"{code}: {message}")
        self.code, self.message, self.field = code, message, field


@dataclass(frozen=True)
class Service:
    """Where the tools send their work and keep what comes back."""

    url: str
    api_key: str | None
    results: Path  # one folder per job: result.glb, report.json


Progress = Callable[[dict[str, Any]], None]


def build(service: Service) -> MCPServer:
    """The server with its tools, the job report resource and the placing prompt."""
    app = MCPServer("ctp", instructions=INSTRUCTIONS, log_level="WARNING")
    work = Work(service)

    @app.tool(name="place")
    async def place(target: Path_, source: Path_,
                    prompt: Annotated[str, Field(min_length=1, description="where the source goes, in one "
                                                 "sentence: \"a cup on the table\", \"a lamp to the left of the "
                                                 "monitor\", \"three apples in the bowl\"")],
                    ctx: Context,
                    target_name: Annotated[str | None, Field(description="what the target is (\"table\"); "
                                                             "default: its file name")] = None,
                    source_name: Annotated[str | None, Field(description="what the source is (\"cup\"); "
                                                             "default: its file name")] = None,
                    preset: PresetArg = None,
                    count: Annotated[int | None, Field(ge=1, le=12, description="copies of the source to place "
                                                       "(default: the prompt's number, else 1)")] = None,
                    arrangement: Annotated[Arrangement | None, Field(description="how several copies stand "
                                                                     "(default: read from the prompt)")] = None,
                    seed: SeedArg = None, options: OptionsArg = None, wait: WaitArg = True,
                    timeout_s: TimeoutArg = 600.0) -> dict[str, Any]:
        """Place the SOURCE mesh relative to the TARGET mesh as the prompt says; the target stays put. Answers
        with `placement`: `matrix` (row-major 4x4, source file frame -> target file frame, glTF axes +Y up) and
        `matrix_z_up` (the same in Blender's axes, +Z up: set it as the source's matrix_world when both were
        exported at the origin), the relation's `verdict` in words ("'on' holds, stable, touching"), `contact`;
        `alternatives` (other poses, the answer first), `target_parts` (the target's named parts the relation
        used), and `glb`, the path of the placed scene (a node per object, named as it). Several copies: `copies`,
        one placement each."""
        options = _options(options, preset=preset, count=count, arrangement=arrangement, seed=seed)
        return await _run(ctx, lambda progress: work.place(target, source, prompt, target_name, source_name,
                                                           options, wait, timeout_s, progress))

    @app.tool(name="compose")
    async def compose(objects: Annotated[list[Path_], Field(min_length=2, description="the meshes of the scene, "
                                                             "each a path as for place")],
                      prompt: Annotated[str, Field(min_length=1, description="the whole scene in one sentence: "
                                                   "\"a plate on the table and a cup on the plate\"")],
                      ctx: Context,
                      names: Annotated[list[str] | None, Field(description="what each object is, in the order of "
                                                               "`objects` (default: the file names)")] = None,
                      preset: PresetArg = None, seed: SeedArg = None, options: OptionsArg = None,
                      wait: WaitArg = True, timeout_s: TimeoutArg = 600.0) -> dict[str, Any]:
        """Build a scene of several meshes from one sentence: the sentence is read into a plan (which object
        stays put, which goes where, in placing order), then every object is placed and every relation judged
        again on the final scene. Answers with the `plan`, `objects` (each one's `matrix` and `matrix_z_up`,
        object file frame -> the scene frame, which is the first ground's file frame, and its `verdict`),
        `all_hold`, `none_intersect` and `glb`, the scene's path (one node per object)."""
        options = _options(options, preset=preset, seed=seed)
        return await _run(ctx, lambda progress: work.compose(objects, prompt, names, options, wait, timeout_s,
                                                             progress))

    @app.tool(name="read_plan")
    async def read_plan(prompt: Annotated[str, Field(min_length=1, description="the scene in one sentence")],
                        names: Annotated[list[str], Field(min_length=2, description="what each object is, in "
                                                          "order")],
                        ctx: Context) -> dict[str, Any]:
        """Read a scene sentence into the plan compose would place, without placing anything (free, instant): the
        object that stays put (`base`), the `steps` in placing order (each with its relation and the objects it
        relates to) and `warnings` (what was assumed). A sentence naming an object that is not in `names` is an
        error (code unknown_object)."""
        return await _run(ctx, lambda _progress: work.read_plan(prompt, names))

    @app.tool(name="inspect")
    async def inspect(mesh: Path_, ctx: Context,
                      up: Annotated[Direction, Field(description="where its up comes from: file (the format's "
                                                     "convention: +Y for glTF), auto (a geometric guess) or an axis "
                                                     "of the file")] = "file",
                      front: Annotated[Direction, Field(description="where its front comes from: file (+Z for "
                                                        "glTF), auto, or an axis at right angles to the up")] = "file",
                      ) -> dict[str, Any]:
        """Read one mesh as a placing job would, without a job: `size` and `extents` (file units), `faces`, the
        `up` and `front` a job will use (unit vectors in the file frame) and why, whether it is `turned` upright.
        `front_trusted` false means no side is known to be its front (a guess, or an object symmetric about its
        up: `front_reason` says which). Named parts (a table's top, its sides) are found by a job: place answers
        with `target_parts`."""
        return await _run(ctx, lambda _progress: work.inspect(mesh, up, front))

    @app.tool(name="job_status")
    async def job_status(job_id: Annotated[str, Field(description="a job id from place or compose")], ctx: Context,
                         wait: Annotated[bool, Field(description="follow it to its end (progress notifications) "
                                                     "instead of answering at once")] = False,
                         timeout_s: TimeoutArg = 600.0) -> dict[str, Any]:
        """A job's status and progress; once it succeeded, its result as place or compose answers it."""
        return await _run(ctx, lambda progress: work.status(job_id, wait, timeout_s, progress))

    @app.tool(name="cancel")
    async def cancel(job_id: Annotated[str, Field(description="a job id from place or compose")],
                     ctx: Context) -> dict[str, Any]:
        """Stop a queued or running job (its status becomes canceled); a job that already ended is an error
        (job_finished)."""
        return await _run(ctx, lambda _progress: work.cancel(job_id))

    @app.resource("ctp://jobs/{job_id}/report.json", name="report", mime_type="application/json")
    async def report(job_id: str) -> str:
        """A succeeded job's full report: every transform, the priors and the names they read, the relation's
        verdict and scores, the guide, timings."""
        return await anyio.to_thread.run_sync(work.report, job_id)

    @app.prompt(name="place_relative")
    def place_relative(object: str, reference: str, relation: str = "on") -> str:
        """Place an object relative to another in the user's 3D scene with ctp."""
        return (f"Place the {object} {relation} the {reference} with the ctp tools, not by guessing coordinates. "
                f"Export the {reference} as a GLB in world coordinates and the {object} as a GLB at its own origin "
                f"(its transforms not applied), call `place` with target = the {reference}'s file, source = the "
                f"{object}'s, prompt \"a {object} {relation} the {reference}\", target_name \"{reference}\" and "
                f"source_name \"{object}\". Tell the user the verdict, then set the {object}'s world matrix to the "
                "answer's `matrix_z_up` (Blender and other Z-up tools) or `matrix` (glTF, Y-up). If the verdict "
                "says the relation does not hold, offer the alternatives.")

    return app


async def _run(ctx: Context, work: Callable[[Progress], dict[str, Any]]) -> dict[str, Any] | CallToolResult:
    """``work`` in a worker thread (the client is synchronous), its job's progress sent as MCP progress
    notifications (only as the job's fraction grows: the protocol has each notification's progress above the
    last), a refusal as a tool error. A request the client cancels answers at once; the thread stops following the
    job at its next event (the job goes on: ``cancel`` stops it)."""
    abandoned = threading.Event()
    sent: list[float] = []

    def progress(job: dict[str, Any]) -> None:
        if abandoned.is_set():
            raise _Abandoned
        step = job.get("progress") or {}
        fraction = float(step.get("fraction") or 0.0)
        if not sent or fraction > sent[-1]:
            sent.append(fraction)
            anyio.from_thread.run(ctx.report_progress, fraction, 1.0, step.get("message") or job["status"])

    try:
        return await anyio.to_thread.run_sync(work, progress, abandon_on_cancel=True)
    except ServiceError as exc:
        return _error(exc.code, exc.message, exc.field, status=exc.status)
    except ToolFailure as exc:
        return _error(exc.code, exc.message, exc.field)
    finally:
        abandoned.set()


class _Abandoned(Exception):
    """Raised in a worker thread whose request was cancelled: it stops following the job."""


def _error(code: str, message: str, field: str | None = None, status: int | None = None) -> CallToolResult:
    error = {k: v for k, v in {"code": code, "message": message, "field": field, "status": status}.items()
             if v is not None}
    text = f"{code}: {message}" + (f" (field {field})" if field else "")
    return CallToolResult(content=[TextContent(type="text", text=text)], structured_content={"error": error},
                          is_error=True)


def _options(options: dict[str, Any] | None, **named: Any) -> dict[str, Any]:
    return {**(options or {}), **{k: v for k, v in named.items() if v is not None}}


class Work:
    """What each tool does, with a client of the service; blocking, run in a worker thread."""

    def __init__(self, service: Service):
        self.service = service

    def place(self, target: str, source: str, prompt: str, target_name: str | None, source_name: str | None,
              options: dict[str, Any], wait: bool, timeout_s: float, progress: Progress) -> dict[str, Any]:
        files = _mesh(target, "target"), _mesh(source, "source")
        with self._client() as client:
            job = client.submit(*files, prompt, target_name=target_name, source_name=source_name,
                                options=options or None)
            return self._follow(client, job["id"], timeout_s, progress) if wait else self._job(client, job)

    def compose(self, objects: list[str], prompt: str, names: list[str] | None, options: dict[str, Any],
                wait: bool, timeout_s: float, progress: Progress) -> dict[str, Any]:
        """The plan first (``POST /plans/read``: a sentence it cannot read is refused before any upload), then the
        scene job."""
        files = [_mesh(path, f"objects.{i}") for i, path in enumerate(objects)]
        names = names if names is not None else [default_name(name, "object") for name, _ in files]
        with self._client() as client:
            plan = client.read_plan(prompt, names)
            job = client.scene(files, prompt, names=names, options=options or None)
            answer = self._follow(client, job["id"], timeout_s, progress) if wait else self._job(client, job)
        return {"plan": plan, **answer}

    def read_plan(self, prompt: str, names: list[str]) -> dict[str, Any]:
        with self._client() as client:
            return client.read_plan(prompt, names)

    def inspect(self, mesh: str, up: str, front: str) -> dict[str, Any]:
        with self._client() as client:
            return client.inspect(_mesh(mesh, "mesh"), up=up, front=front)

    def status(self, job_id: str, wait: bool, timeout_s: float, progress: Progress) -> dict[str, Any]:
        with self._client() as client:
            return self._follow(client, job_id, timeout_s, progress) if wait else self._job(client,
                                                                                           client.status(job_id))

    def cancel(self, job_id: str) -> dict[str, Any]:
        with self._client() as client:
            return self._job(client, client.cancel(job_id))

    def report(self, job_id: str) -> str:
        with self._client() as client:
            return client.download(job_id, "report.json").decode()

    def _client(self) -> Client:
        return _Reachable(self.service)

    def _follow(self, client: Client, job_id: str, timeout_s: float, progress: Progress) -> dict[str, Any]:
        try:
            job = client.wait(job_id, on_progress=progress, timeout_s=timeout_s)
        except TimeoutError:
            job = client.status(job_id)
        return self._job(client, job)

    def _job(self, client: Client, job: dict[str, Any]) -> dict[str, Any]:
        """The job in a few fields; a failed one as its error, a succeeded one with its result (downloaded)."""
        if job["status"] == "failed":
            error = job.get("error") or {}
            raise ToolFailure(error.get("code", "job_failed"),
                              f"job {job['id']} failed: {error.get('message', 'no reason given')}")
        step = job.get("progress") or {}
        answer = {"job_id": job["id"], **{k: job[k] for k in JOB_FIELDS if job.get(k) is not None},
                  "progress": {k: step[k] for k in ("fraction", "message", "eta_s") if step.get(k) is not None}}
        if job["status"] != "succeeded":
            return answer
        folder = self.service.results / job["id"]
        folder.mkdir(parents=True, exist_ok=True)
        report = json.loads(client.download(job["id"], "report.json", to=folder / "report.json"))
        client.download(job["id"], "result.glb", to=folder / "result.glb")
        return {**answer, **result(report), "glb": str(folder / "result.glb"),
                "report": str(folder / "report.json"), "report_resource": f"ctp://jobs/{job['id']}/report.json"}


class _Reachable(Client):
    """A client whose connection failures are a ``ToolFailure`` saying where it looked for the service."""

    def __init__(self, service: Service):
        super().__init__(service.url, service.api_key)
        self.url = service.url

    def __exit__(self, kind, exc, traceback) -> None:
        self.close()
        if isinstance(exc, httpx.TransportError):
            raise ToolFailure("service_unavailable", f"no ctp service answered at {self.url} ({exc}); start one "
                              "with `make serve` (or `ctp serve`), or name it with `ctp mcp --service URL`") from None


def _mesh(path: str, field: str) -> tuple[str, bytes]:
    """A mesh file's name and bytes; a missing or unreadable file as a tool error on ``field``."""
    file = Path(path).expanduser()
    if not file.is_file():
        raise ToolFailure("file_not_found", f"{path}: no such file on the machine the ctp MCP server runs on "
                          f"(its working directory: {Path.cwd()})", field)
    try:
        return file.name, file.read_bytes()
    except OSError as exc:
        raise ToolFailure("file_unreadable", f"{path}: {exc.strerror or exc}", field) from None


def result(report: dict[str, Any]) -> dict[str, Any]:
    """What a report says of where things go, for a model to read: a pair's placement and alternatives, each copy
    of several of a kind, or each object of a scene, with both axis conventions and the verdict in words."""
    if report.get("stages") is not None:
        judged = {r["name"]: r for r in (report.get("whole") or {}).get("relations", [])}
        whole = report.get("whole") or {}
        return {"objects": [{"name": o["name"], **_matrices(o["transform"]),
                             "verdict": _scene_verdict(judged.get(o["name"]))} for o in report["objects"]],
                "all_hold": whole.get("all_hold"), "none_intersect": whole.get("none_intersect"),
                "warnings": [w for stage in report["stages"] for w in stage.get("warnings", [])]}
    found = {"guide": report.get("guide"), "warnings": report.get("warnings", []),
             "target_parts": (report.get("extra") or {}).get("parts", [])}
    if report.get("copies"):
        return {**found, "copies": [{"name": c["name"], **_matrices(c["transform"]),
                                     "verdict": verdict(c.get("relation"))} for c in report["copies"]]}
    placement = {**_matrices(report["transform"]), "verdict": verdict(report.get("relation"), report.get("contact")),
                 "relation": report.get("relation"), "contact": report.get("contact")}
    alternatives = [{**_matrices(a["transform"]), "verdict": verdict(a.get("relation"), a.get("contact")),
                     "contact": a.get("contact")} for a in report.get("alternatives") or []]
    return {**found, "placement": placement, "alternatives": alternatives}


def _matrices(transform: dict[str, Any]) -> dict[str, Any]:
    return {"matrix": transform["matrix"], "matrix_z_up": z_up(transform["matrix"]).round(9).tolist(),
            "from_frame": transform["from_frame"], "to_frame": transform["to_frame"]}


def verdict(relation: dict[str, Any] | None, contact: dict[str, Any] | None = None) -> str:
    """``'on' holds, stable, touching``: the geometry's judgement of the prompt's relation and whether the source
    touches the target (the report's ``relation`` and ``contact``; the Blender add-on's panel, a stdlib-only copy in
    ``integrations/blender/report.py``, says a gap as a share of the source's size instead)."""
    if not relation:
        return "no relation read from the prompt"
    words = [f"'{relation['name']}' {'holds' if relation['holds'] else 'does not hold'}"]
    if relation.get("stable") is not None:
        words.append("stable" if relation["stable"] else "not stable")
    if contact:
        words.append("touching" if contact["touching"] else f"{contact['gap']:.2f} source diagonals from touching")
    if relation.get("note"):
        words.append(relation["note"])
    return ", ".join(words)


def _scene_verdict(judged: dict[str, Any] | None) -> str:
    """An object of a scene as judged again on the final scene (the report's ``whole``); the base has none."""
    if judged is None:
        return "stays put (the scene's frame)"
    on = " and ".join(judged.get("on") or [])
    words = [f"'{judged['relation']}' {on} {'holds' if judged['holds'] else 'does not hold'}"]
    if judged.get("stable") is not None:
        words.append("stable" if judged["stable"] else "not stable")
    words.append("intersects another object" if judged.get("intersects") else "intersects nothing")
    return ", ".join(words)
