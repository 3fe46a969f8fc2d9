"""Object names: one rule for an object the user did not name, in the CLI, the service and the Python client."""

from __future__ import annotations

import json

import httpx

from ctp_core.reading.names import NAME_MAX, default_name
from service.client import Client


def test_default_name_reads_the_file_name():
    assert default_name("coffee_cup.glb", "source") == "coffee cup"
    assert default_name("dir/Owl-Barn_01.obj.zip", "source") == "Owl Barn 01.obj"
    assert default_name("_-_.ply", "target") == "target"
    assert default_name("x" * 300 + ".stl", "source") == "x" * NAME_MAX


def test_the_client_names_steps_as_the_service_does():
    """The client renames uploaded parts ("0-coffee_cup.glb"), so it must send the name the rule gives the file."""
    seen = {}

    def handler(request: httpx.Request) -> httpx.Response:
        body = request.content.decode("latin-1")
        plan = body.split('name="plan"', 1)[1].split("\r\n\r\n", 1)[1].split("\r\n--", 1)[0]
        seen["plan"] = json.loads(plan)
        return httpx.Response(202, json={"id": "x", "status": "queued", "links": {}})

    with Client("http://ctp.test", transport=httpx.MockTransport(handler)) as client:
        client.assemble(("table.glb", b"glb"), [{"file": ("coffee_cup.glb", b"glb"), "prompt": "a cup on it"}])
    assert [step["name"] for step in seen["plan"]] == ["coffee cup"]
