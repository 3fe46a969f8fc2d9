"""``ctp mcp`` driven by the MCP SDK's own client, over stdio (the server as a child process) and over streamable
HTTP (``ctp mcp --http`` on a loopback port), against a real service (uvicorn, a private Redis, one ``ctp worker``)
with the fast preset and no guide."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Awaitable, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

import anyio
import httpx
import numpy as np
import pytest
import trimesh
from mcp import ClientSession, StdioServerParameters, stdio_client
from mcp.client.streamable_http import streamable_http_client

from ctp.cmd_serve import stop_processes
from ctp_core.io.examples import get_example, write_table_setting
from service.embedded import free_port
from tests.conftest import REPO, service_env, wait_for

FAST = {"preset": "test", "seed": 1}
TABLE_TOP, TABLE_HALF = 0.75, (0.6, 0.4)  # ctp_core.io.examples' table: top height, half width (x) and depth (z)
TOOLS = {"place", "compose", "read_plan", "inspect", "job_status", "cancel"}


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "mcp", model="auto")  # an empty model cache: no guide, seconds a job


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """The example pair (table.glb, cup.glb) and the table setting (plate.glb too) in one folder."""
    folder = tmp_path_factory.mktemp("meshes")
    get_example("cup-on-table").write(folder)
    write_table_setting(folder)
    (folder / "broken.glb").write_bytes(b"glTF but not really")
    return folder


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("mcp-results")


def _command(api, results: Path) -> list[str]:
    return ["-m", "ctp", "mcp", "--service", api.url, "--results", str(results)]


@pytest.fixture(scope="module")
def http_server(api, worker, results, tmp_path_factory):
    """``ctp mcp --http`` on a free loopback port; its URL."""
    port = free_port()
    log = open(tmp_path_factory.mktemp("mcp-http") / "mcp.log", "wb")  # noqa: SIM115 - closed below
    process = subprocess.Popen([sys.executable, *_command(api, results), "--http", "--port", str(port)], cwd=REPO,
                               stdout=log, stderr=subprocess.STDOUT)

    def up() -> bool:
        try:
            return httpx.get(f"http://127.0.0.1:{port}/mcp", timeout=1).status_code > 0
        except httpx.TransportError:
            assert process.poll() is None, "ctp mcp --http exited"
            return False

    try:
        wait_for(up, 60, "ctp mcp --http to listen")
        yield f"http://127.0.0.1:{port}/mcp"
    finally:
        stop_processes([process], grace_s=5)
        log.close()


@pytest.fixture(params=["stdio", "http"])
def transport(request):
    return request.param


@pytest.fixture
def connect(request, api, worker, results, tmp_path) -> Callable[[str], Any]:
    """``connect(transport)``: an async context manager giving an initialised ``ClientSession``."""

    @asynccontextmanager
    async def session(kind: str):
        if kind == "stdio":
            parameters = StdioServerParameters(command=sys.executable, args=_command(api, results), cwd=REPO,
                                               env={"OMP_WAIT_POLICY": "PASSIVE"})
            with open(tmp_path / "mcp-stdio.log", "w") as errlog:
                async with stdio_client(parameters, errlog=errlog) as streams, ClientSession(*streams) as client:
                    await client.initialize()
                    yield client
        else:
            url = request.getfixturevalue("http_server")
            async with streamable_http_client(url) as streams, ClientSession(*streams) as client:
                await client.initialize()
                yield client

    return session


def drive(connect, kind: str, body: Callable[[ClientSession], Awaitable[Any]], timeout_s: float = 120) -> Any:
    """Run ``body`` with a session of ``kind``; fails (no hang) after ``timeout_s``."""

    async def main():
        with anyio.fail_after(timeout_s):
            async with connect(kind) as client:
                return await body(client)

    return anyio.run(main)


def _error(result) -> dict[str, Any]:
    assert result.is_error, result
    return result.structured_content["error"]


def test_lists_the_tools_with_schemas_a_resource_and_a_prompt(connect):
    async def body(client: ClientSession):
        return (await client.list_tools(), await client.list_resource_templates(), await client.list_prompts())

    tools, templates, prompts = drive(connect, "stdio", body)
    by_name = {tool.name: tool for tool in tools.tools}
    assert set(by_name) == TOOLS
    for tool in by_name.values():
        assert len(tool.description) > 60, tool.name  # written for a model to read
        properties = tool.input_schema["properties"]
        assert all(p.get("description") for p in properties.values()), tool.name
    assert set(by_name["place"].input_schema["required"]) == {"target", "source", "prompt"}
    assert {"preset", "count", "arrangement", "seed"} <= set(by_name["place"].input_schema["properties"])
    assert [t.uri_template for t in templates.resource_templates] == ["ctp://jobs/{job_id}/report.json"]
    assert [p.name for p in prompts.prompts] == ["place_relative"]


def _cup_on_table(answer: dict[str, Any], cup: trimesh.Trimesh) -> None:
    """The cup's bottom at the table's top and inside its footprint: by the returned matrix, by the Z-up one (the
    same place in Blender's axes) and in the returned GLB."""
    matrix = np.array(answer["placement"]["matrix"])
    placed = trimesh.transform_points(cup.vertices, matrix)
    assert placed[:, 1].min() == pytest.approx(TABLE_TOP, abs=0.01)
    assert np.all(np.abs(placed[:, [0, 2]]) < TABLE_HALF)
    # Blender's axes: glTF (x, y, z) is (x, -z, y) there; the cup's up is +Z and the table's top at z = 0.75
    z_up_cup = cup.vertices[:, [0, 2, 1]] * [1, -1, 1]
    in_z_up = trimesh.transform_points(z_up_cup, np.array(answer["placement"]["matrix_z_up"]))
    assert in_z_up[:, 2].min() == pytest.approx(TABLE_TOP, abs=0.01)
    assert np.allclose(in_z_up[:, [0, 1, 2]], placed[:, [0, 2, 1]] * [1, -1, 1], atol=1e-6)
    scene = trimesh.load(answer["glb"], force="scene")
    nodes = {node: scene.graph[node] for node in scene.graph.nodes_geometry}
    assert set(nodes) == {"table", "cup"}
    matrix, geometry = nodes["cup"]
    served = trimesh.transform_points(scene.geometry[geometry].vertices, matrix)
    assert served[:, 1].min() == pytest.approx(TABLE_TOP, abs=0.01)
    assert np.all(np.abs(served[:, [0, 2]]) < TABLE_HALF)


def test_place_puts_the_cup_on_the_table_with_progress(connect, transport, files):
    steps: list[tuple[float, float | None, str | None]] = []

    async def progress(value, total, message):
        steps.append((value, total, message))

    async def body(client: ClientSession):
        placed = await client.call_tool("place", {
            "target": str(files / "table.glb"), "source": str(files / "cup.glb"), "prompt": "a cup on the table",
            "target_name": "table", "source_name": "cup", **FAST}, progress_callback=progress)
        assert not placed.is_error, placed.content
        report = await client.read_resource(placed.structured_content["report_resource"])
        return placed.structured_content, report

    answer, report = drive(connect, transport, body)
    assert answer["status"] == "succeeded"
    assert answer["placement"]["verdict"].startswith("'on' holds")
    assert answer["placement"]["contact"]["touching"] is True
    assert answer["alternatives"] and all(a["verdict"] for a in answer["alternatives"])
    assert any("top" in part for part in answer["target_parts"])
    _cup_on_table(answer, trimesh.load(files / "cup.glb", force="mesh"))
    assert steps and steps[-1][:2] == (1.0, 1.0) and all(message for *_, message in steps)  # the last at the end
    assert all(a[0] < b[0] for a, b in zip(steps, steps[1:], strict=False))  # each above the last, as MCP has it
    assert json.loads(report.contents[0].text)["transform"]["matrix"] == answer["placement"]["matrix"]


def test_place_several_copies(connect, files):
    """One placement per copy, each as the report has it, its verdict in words (the fast preset need not make
    both hold: the words must say which)."""
    async def body(client: ClientSession):
        placed = await client.call_tool("place", {
            "target": str(files / "table.glb"), "source": str(files / "cup.glb"), "prompt": "two cups on the table",
            "target_name": "table", "source_name": "cup", "count": 2, "arrangement": "row", **FAST})
        assert not placed.is_error, placed.content
        report = await client.read_resource(placed.structured_content["report_resource"])
        return placed.structured_content["copies"], json.loads(report.contents[0].text)["copies"]

    copies, reported = drive(connect, "http", body)
    assert [c["name"] for c in copies] == [c["name"] for c in reported] == ["cup_1", "cup_2"]
    for copy, truth in zip(copies, reported, strict=True):
        assert copy["matrix"] == truth["transform"]["matrix"]
        holds = truth["relation"]["holds"]
        assert copy["verdict"].startswith("'on' holds" if holds else "'on' does not hold")


def test_compose_places_a_three_object_sentence(connect, files):
    async def body(client: ClientSession):
        return await client.call_tool("compose", {
            "objects": [str(files / f"{n}.glb") for n in ("table", "plate", "cup")],
            "prompt": "a plate on the table and a cup on the plate", **FAST})

    result = drive(connect, "stdio", body)
    assert not result.is_error, result.content
    answer = result.structured_content
    assert answer["plan"]["base"] == "table"
    assert [(s["name"], s["on"]) for s in answer["plan"]["steps"]] == [("plate", ["table"]), ("cup", ["plate"])]
    objects = {o["name"]: o for o in answer["objects"]}
    assert set(objects) == {"table", "plate", "cup"}
    assert objects["cup"]["verdict"].startswith("'on' plate ")
    scene = trimesh.load(answer["glb"], force="scene")
    bounds = {node: scene.geometry[g].copy().apply_transform(m).bounds
              for node in scene.graph.nodes_geometry for m, g in [scene.graph[node]]}
    assert set(bounds) == {"table", "plate", "cup"}
    assert bounds["plate"][0][1] == pytest.approx(TABLE_TOP, abs=0.01)  # the plate on the table's top
    assert bounds["cup"][0][1] == pytest.approx(bounds["plate"][1][1], abs=0.03)  # the cup on the plate


def test_bad_input_is_a_tool_error_with_its_code(connect, files):
    async def body(client: ClientSession):
        unknown = await client.call_tool("read_plan", {"prompt": "a lamp on the table", "names": ["table", "cup"]})
        plan = await client.call_tool("read_plan", {"prompt": "a cup on the table", "names": ["table", "cup"]})
        missing = await client.call_tool("place", {"target": str(files / "nowhere.glb"),
                                                   "source": str(files / "cup.glb"), "prompt": "a cup on it"})
        broken = await client.call_tool("inspect", {"mesh": str(files / "broken.glb")})
        inspected = await client.call_tool("inspect", {"mesh": str(files / "table.glb")})
        return unknown, plan, missing, broken, inspected

    unknown, plan, missing, broken, inspected = drive(connect, "http", body)
    assert _error(unknown)["code"] == "unknown_object"
    assert "lamp" in unknown.content[0].text and "Traceback" not in unknown.content[0].text
    assert not plan.is_error and plan.structured_content["steps"][0]["name"] == "cup"
    assert _error(missing) == {"code": "file_not_found", "field": "target", "message": missing.content[0].text
                               .removeprefix("file_not_found: ").removesuffix(" (field target)")}
    assert _error(broken)["code"] == "mesh_unreadable" and _error(broken)["status"] == 422
    table = inspected.structured_content
    assert table["up"] == [0.0, 1.0, 0.0] and table["size"] == pytest.approx(1.2)


def test_cancel_a_running_job(connect, api, files):
    """A request the client gives up on answers at once and leaves its job running; ``cancel`` stops the job. A job
    started without waiting is followed to its result by ``job_status``."""
    pair = {"target": str(files / "table.glb"), "source": str(files / "cup.glb"), "prompt": "a cup on the table",
            **FAST}
    before = {job["id"] for job in api.client.get("/jobs").json()["jobs"]}

    async def body(client: ClientSession):
        with anyio.move_on_after(3) as given_up:
            await client.call_tool("place", {**pair, "options": {"steps": 100000}})  # it would take minutes
        assert given_up.cancelled_caught
        started = [job for job in api.client.get("/jobs").json()["jobs"] if job["id"] not in before]
        assert len(started) == 1 and started[0]["status"] == "running"
        job_id = started[0]["id"]
        canceled = await client.call_tool("cancel", {"job_id": job_id})
        final = await client.call_tool("job_status", {"job_id": job_id, "wait": True, "timeout_s": 60})
        again = await client.call_tool("cancel", {"job_id": job_id})
        queued = await client.call_tool("place", {**pair, "wait": False})
        followed = await client.call_tool("job_status", {"job_id": queued.structured_content["job_id"],
                                                         "wait": True, "timeout_s": 60})
        return canceled, final, again, queued, followed

    canceled, final, again, queued, followed = drive(connect, "stdio", body)
    assert not canceled.is_error, canceled.content
    assert final.structured_content["status"] == "canceled"
    assert _error(again)["code"] == "job_finished"
    assert queued.structured_content["status"] in ("queued", "running") and "placement" not in queued.structured_content
    assert followed.structured_content["status"] == "succeeded"
    assert followed.structured_content["placement"]["verdict"].startswith("'on' holds")


def test_no_service_is_a_tool_error_naming_it(tmp_path):
    async def body():
        parameters = StdioServerParameters(command=sys.executable, cwd=REPO, args=[
            "-m", "ctp", "mcp", "--service", f"http://127.0.0.1:{free_port()}", "--results", str(tmp_path)])
        with open(tmp_path / "mcp-stdio.log", "w") as errlog, anyio.fail_after(60):
            async with stdio_client(parameters, errlog=errlog) as streams, ClientSession(*streams) as client:
                await client.initialize()
                return await client.call_tool("read_plan", {"prompt": "a cup on the table", "names": ["a", "b"]})

    result = anyio.run(body)
    assert _error(result)["code"] == "service_unavailable"
    assert "make serve" in result.content[0].text
