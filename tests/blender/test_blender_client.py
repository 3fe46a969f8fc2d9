"""The add-on's HTTP client (standard library only, as inside Blender) against a scripted server on a loopback
socket: the answers a healthy test service never gives (429, 503 with Retry-After, 401)."""

import contextlib
import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import pytest


@contextlib.contextmanager
def scripted(answers: list[tuple[int, dict[str, str], dict]]):
    """A server that gives ``answers`` (status, headers, JSON body) in turn, one per request; yields its URL and
    the Authorization header of each request."""
    seen: list[str | None] = []

    class Handler(BaseHTTPRequestHandler):
        def answer(self) -> None:
            self.rfile.read(int(self.headers.get("Content-Length") or 0))
            seen.append(self.headers.get("Authorization"))
            status, headers, body = answers.pop(0)
            data = json.dumps(body).encode()
            self.send_response(status)
            for name, value in {**headers, "Content-Type": "application/json"}.items():
                self.send_header(name, value)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        do_GET = do_POST = do_DELETE = answer

        def log_message(self, *args) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_port}", seen
    finally:
        server.shutdown()
        server.server_close()


def error(code: str, message: str) -> dict:
    return {"error": {"code": code, "message": message, "field": None}}


def test_blender_client_waits_out_a_429_retry_after(addon, tmp_path):
    glb = tmp_path / "x.glb"
    glb.write_bytes(b"glTF")
    answers = [(429, {"Retry-After": "1"}, error("too_many_jobs", "2 jobs of this key are running")),
               (202, {}, {"id": "j1", "status": "queued"})]
    with scripted(answers) as (url, seen):
        waits: list[str] = []
        client = addon.client.Client(url, "secret", on_wait=waits.append)
        started = time.monotonic()
        assert client.submit(glb, glb, {"prompt": "a cup on the table"})["id"] == "j1"
    assert time.monotonic() - started >= 1.0
    assert seen == ["Bearer secret", "Bearer secret"]
    assert len(waits) == 1 and "2 jobs of this key are running" in waits[0] and "again in 1 s" in waits[0]


def test_blender_client_says_a_long_retry_after_instead_of_waiting(addon):
    with scripted([(503, {"Retry-After": "120"}, error("no_worker", "no worker is live"))]) as (url, _):
        started = time.monotonic()
        with pytest.raises(addon.client.ServiceError) as raised:
            addon.client.Client(url).status("j1")
    assert time.monotonic() - started < 5
    assert str(raised.value) == "no worker is live (no_worker; the service asks to try again in 120 s)"


def test_blender_client_401_says_where_the_key_goes(addon):
    refused = (401, {}, error("unauthorized", "send Authorization: Bearer <API key>"))
    with scripted([refused, refused]) as (url, seen):
        with pytest.raises(addon.client.ServiceError, match="needs an API key.*add-on's preferences"):
            addon.client.Client(url).status("j1")
        with pytest.raises(addon.client.ServiceError, match="refused the API key.*add-on's preferences"):
            addon.client.Client(url, "wrong").status("j1")
    assert seen == [None, "Bearer wrong"]
