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
    """A server that gives ``answers`` (status, headers, JSON body; ``{url}`` in a header is its own URL) in turn,
    one per request; yields its URL and the path and Authorization header of each request."""
    seen: list[tuple[str, str | None]] = []

    class Handler(BaseHTTPRequestHandler):
        def answer(self) -> None:
            self.rfile.read(int(self.headers.get("Content-Length") or 0))
            seen.append((self.path, self.headers.get("Authorization")))
            status, headers, body = answers.pop(0)
            data = json.dumps(body).encode()
            self.send_response(status)
            for name, value in {**headers, "Content-Type": "application/json"}.items():
                self.send_header(name, value.format(url=f"http://127.0.0.1:{self.server.server_port}"))
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
    assert seen == [("/align", "Bearer secret"), ("/align", "Bearer secret")]
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
    assert [key for _, key in seen] == [None, "Bearer wrong"]


def test_blender_client_follows_a_download_redirect_without_the_key(addon):
    """A deployment with presigned downloads answers 307 to the store: the key must not go there."""
    with scripted([(307, {"Location": "{url}/presigned/report.json?signature=s"}, {}),
                   (200, {}, {"transform": None})]) as (url, seen):
        assert addon.client.Client(url, "secret").report("j1") == {"transform": None}
    assert seen == [("/jobs/j1/report.json", "Bearer secret"), ("/presigned/report.json?signature=s", None)]


def test_blender_report_in_other_frames_is_refused(addon):
    """The add-on's formula is for source file -> target file; a report that says otherwise is not guessed at."""
    transform = {"from_frame": "source_local", "to_frame": "normalised", "matrix": [[1, 0, 0, 0]] * 4}
    with pytest.raises(ValueError, match="source_local to normalised"):
        addon.report.placements({"transform": transform, "relation": None})
