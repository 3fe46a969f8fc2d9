"""A small Python client for the ctp HTTP API (httpx only; ``ctp_core`` does not depend on it).

    client = Client("http://127.0.0.1:8000", api_key=None)
    job = client.submit("sundae.glb", "cherry.glb", "a cherry on top of a sundae", options={"seed": 1})
    final = client.wait(job["id"], on_progress=lambda j: print(j["progress"]["message"]))
    client.download(job["id"], "result.glb", to="scene.glb")

    # moved by hand 0.2 up, dropped back into contact and saved as the job's result (original.glb keeps the run's):
    moved = json.loads(client.download(job["id"], "report.json"))["transform"]["matrix"]
    moved[1][3] += 0.2
    done = client.adjust(job["id"], moved, settle="drop", save=True)  # done["result"]: transform, contact_gap, ...

    # one more object on that scene (its objects stay as they are), or a whole scene as one job:
    spoon = client.submit(None, "spoon.glb", "a spoon in the cup", target_job=job["id"])
    scene = client.assemble("table.glb", [{"file": "plate.glb", "prompt": "a plate on the table"},
                                          {"file": "cup.glb", "prompt": "a cup on the plate"}])

    # called back when it ends, safe to retry (one job per key), answered at once if done within 30 s:
    job = client.submit("sundae.glb", "cherry.glb", "a cherry on top of a sundae", webhook="https://example.com/hook",
                        idempotency_key=str(uuid.uuid4()), wait=30)
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator, Sequence
from datetime import UTC, datetime
from email.utils import parsedate_to_datetime
from pathlib import Path
from typing import Any

import httpx

from ctp_core.reading.names import default_name

MeshInput = str | Path | tuple[str, bytes]  # a path, or (file name with extension, bytes)
TERMINAL = ("succeeded", "failed", "canceled")


class ServiceError(Exception):
    """An error answer of the API: HTTP status plus its stable ``code``, ``message`` and ``field``;
    ``retry_after_s``: the answer's ``Retry-After`` (429, 503), None without one."""

    def __init__(self, status: int, code: str, message: str, field: str | None = None,
                 retry_after_s: float | None = None):
        super().__init__(f"{status} {code}: {message}" + (f" (field {field})" if field else ""))
        self.status, self.code, self.message, self.field = status, code, message, field
        self.retry_after_s = retry_after_s


class _Http(httpx.Client):
    """An ``httpx.Client`` that honours ``Retry-After``: a 429 or 503 that carries one is sent again after that many
    seconds, at most ``retries`` times and only while the wait is at most ``max_wait_s`` (a longer one is the
    caller's to decide: the ``ServiceError`` carries it). The service answers both before it has done anything (no
    job is queued), so resending is safe."""

    def __init__(self, *, retries: int, max_wait_s: float, **kwargs):
        super().__init__(**kwargs)
        self.retries, self.max_wait_s = retries, max_wait_s

    def send(self, request: httpx.Request, **kwargs) -> httpx.Response:
        for _ in range(self.retries):
            response = super().send(request, **kwargs)
            wait_s = retry_after(response)
            if wait_s is None or wait_s > self.max_wait_s:
                return response
            response.close()
            time.sleep(wait_s)
        return super().send(request, **kwargs)


def retry_after(response: httpx.Response) -> float | None:
    """The seconds a 429 or 503 asks the client to wait (``Retry-After``: seconds or an HTTP date); None for
    another status, or without the header."""
    value = response.headers.get("retry-after") if response.status_code in (429, 503) else None
    if value is None:
        return None
    if value.strip().isdigit():
        return float(value)
    try:
        return max(0.0, (parsedate_to_datetime(value) - datetime.now(UTC)).total_seconds())
    except (TypeError, ValueError):
        return None


class Client:
    """``retries`` / ``max_wait_s``: how often and how long a request refused with a ``Retry-After`` (429
    ``too_many_jobs``, a 503 while part of the service restarts) is sent again before ``ServiceError`` is raised."""

    def __init__(self, url: str, api_key: str | None = None, *, timeout_s: float = 60.0,
                 transport: httpx.BaseTransport | None = None, retries: int = 3, max_wait_s: float = 30.0):
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self.http = _Http(base_url=url, headers=headers, timeout=timeout_s, transport=transport, retries=retries,
                          max_wait_s=max_wait_s)

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def submit(self, target: MeshInput | None, source: MeshInput, prompt: str | None = None, *,
               image: MeshInput | None = None, options: dict[str, Any] | None = None,
               target_name: str | None = None, source_name: str | None = None,
               target_job: str | None = None, on: str | Sequence[str] | None = None, webhook: str | None = None,
               webhook_events: Sequence[str] | None = None, idempotency_key: str | None = None,
               wait: int | None = None, queue: str | None = None) -> dict[str, Any]:
        """Upload a pair; returns ``{id, status, links}`` (queued), or the whole job (as ``status``) when it
        ended within ``wait`` seconds or ``idempotency_key`` was used before for this same request. Needs a
        prompt or an image.

        ``target_job`` (with ``target`` None) uses that succeeded job's result scene as the target; ``on``
        names the object of it the source relates to, or a list of two ("between"; default: the last placed
        one). ``webhook``: a URL the job's ``webhook_events`` (default ``completed``) are POSTed to, signed.
        ``idempotency_key``: a retry with the same key answers the first request's job instead of starting
        another (``ServiceError`` 409 ``idempotency_conflict`` when the request differs). ``wait``: up to 60 s
        (``Prefer: wait``). ``queue``: the named queue to run on (option ``queue``; default the service's)."""
        options = _with_queue(options, queue)
        files = {"source": _file(source)}
        if target is not None:
            files["target"] = _file(target)
        if image is not None:
            files["image"] = _file(image)
        data = {k: v for k, v in {"prompt": prompt, "target_name": target_name, "source_name": source_name,
                                  "target_job": target_job, "on": [on] if isinstance(on, str) else on,
                                  "options": json.dumps(options) if options else None,
                                  **_webhook(webhook, webhook_events)}.items() if v is not None}
        return self._submit("/align", files, data, idempotency_key, wait)

    def assemble(self, base: MeshInput, steps: list[dict[str, Any]], *, options: dict[str, Any] | None = None,
                 base_name: str | None = None, webhook: str | None = None,
                 webhook_events: Sequence[str] | None = None, idempotency_key: str | None = None,
                 wait: int | None = None, queue: str | None = None) -> dict[str, Any]:
        """Submit a whole scene as one job; returns ``{id, status, links}``, or the job (``webhook``,
        ``idempotency_key``, ``wait`` and ``queue`` as in ``submit``).

        Each step is ``{"file": MeshInput, "prompt": str}`` or ``{"file": ..., "image": MeshInput}``, with
        optional ``name`` (default from the file name, as the CLI and the service name it:
        ``names.default_name``), ``on`` (a placed object's name; default the last placed) and ``options`` (this
        step's AlignOptions). ``queue`` as for ``submit``."""
        options = _with_queue(options, queue)
        files: list[tuple[str, tuple[str, bytes]]] = [("base", _file(base))]
        plan = []
        for i, step in enumerate(steps):
            entry = {k: v for k, v in step.items() if k not in ("file", "image")}
            name, data = _file(step["file"])
            entry.setdefault("name", default_name(name, "object"))
            entry["file"] = f"{i}-{name}"  # distinct part names, whatever the files are called
            files.append(("source", (entry["file"], data)))
            if step.get("image") is not None:
                image_name, image = _file(step["image"])
                entry["image"] = f"{i}-{image_name}"
                files.append(("image", (entry["image"], image)))
            plan.append(entry)
        data = {k: v for k, v in {"plan": json.dumps(plan), "base_name": base_name,
                                  "options": json.dumps(options) if options else None,
                                  **_webhook(webhook, webhook_events)}.items() if v is not None}
        return self._submit("/assemble", files, data, idempotency_key, wait)

    def read_plan(self, prompt: str, names: Sequence[str]) -> dict[str, Any]:
        """The plan ``scene`` would place, read from ``prompt`` over the objects ``names`` (``POST /plans/read``),
        with its ``warnings``; queues nothing. A sentence the reader refuses raises ``ServiceError`` 422 with the
        reader's code (``unknown_object``, ``placement_cycle``, ...)."""
        return self._json(self.http.post("/plans/read", json={"prompt": prompt, "names": list(names)}))

    def scene(self, objects: Sequence[MeshInput], prompt: str, *, names: Sequence[str] | None = None,
              options: dict[str, Any] | None = None, idempotency_key: str | None = None,
              wait: int | None = None, queue: str | None = None) -> dict[str, Any]:
        """A scene from one sentence as one job (``POST /scenes``); returns ``{id, status, links}``, or the job
        (``idempotency_key``, ``wait`` and ``queue`` as in ``submit``). ``names``: what each object is, in order
        (default from the file names, as ``assemble`` names them)."""
        options = _with_queue(options, queue)
        files = [_file(item) for item in objects]
        names = list(names) if names is not None else [default_name(name, "object") for name, _ in files]
        parts = [("object", (f"{i}-{name}", data)) for i, (name, data) in enumerate(files)]  # distinct part names
        data = {k: v for k, v in {"prompt": prompt, "names": json.dumps(names),
                                  "options": json.dumps(options) if options else None}.items() if v is not None}
        return self._submit("/scenes", parts, data, idempotency_key, wait)

    def _submit(self, path: str, files, data: dict[str, str], idempotency_key: str | None,
                wait: int | None) -> dict[str, Any]:
        headers = {"Idempotency-Key": idempotency_key} if idempotency_key is not None else {}
        timeout = self.http.timeout
        if wait is not None:
            headers["Prefer"] = f"wait={wait}"
            timeout = httpx.Timeout(timeout.connect, read=(timeout.read or 0) + wait)  # the answer comes after it
        return self._json(self.http.post(path, files=files, data=data, headers=headers, timeout=timeout))

    def inspect(self, mesh: MeshInput, *, up: str = "file", front: str = "file") -> dict[str, Any]:
        """What a job would make of one mesh, before any job (``POST /inspect``): ``faces``, ``vertices``,
        ``extents`` and ``size`` in the file's units, the ``up`` and ``front`` a job with the options ``up`` and
        ``front`` will use (file frame), whether it is ``turned`` and why; a file a job would refuse raises
        ``ServiceError`` with the same code."""
        return self._json(self.http.post("/inspect", files={"mesh": _file(mesh)}, data={"up": up, "front": front}))

    def adjust(self, job_id: str, transform, *, settle: str = "none", direction: Sequence[float] | None = None,
               save: bool = False, object_name: str | None = None, wait: int = 30,
               timeout_s: float = 120.0) -> dict[str, Any]:
        """Adjust a succeeded job by hand (``POST /jobs/{id}/adjust``) and return the ended adjustment:
        ``transform`` (4x4, source file -> target file, row-major; a numpy array will do; for a scene's object
        ``object_name``, its file frame -> the scene) measured there, after ``settle`` "drop" (along the
        target's up) or "push" (along ``direction``, target file frame) into contact, and with ``save`` stored
        as the job's result (``original.glb`` keeps the run's own). Its ``status`` is succeeded or failed
        (``error``); its ``result`` has the ``transform`` it ended at, ``penetration``, ``contact_gap``,
        ``touching``, ``settled``, ``relation``, and for a scene ``whole`` (every relation judged again) and
        ``stands_on``. Waits ``wait`` s in the request (``Prefer: wait``), then reads it until it ends;
        ``TimeoutError`` after ``timeout_s``."""
        body: dict[str, Any] = {"transform": [list(map(float, row)) for row in transform], "settle": settle,
                                "save": save}
        if direction is not None:
            body["direction"] = [float(v) for v in direction]
        if object_name is not None:
            body["object"] = object_name
        timeout = httpx.Timeout(self.http.timeout.connect, read=(self.http.timeout.read or 0) + wait)
        adjustment = self._json(self.http.post(f"/jobs/{job_id}/adjust", json=body, headers={"Prefer": f"wait={wait}"},
                                               timeout=timeout))
        deadline = time.monotonic() + timeout_s
        while adjustment["status"] not in ("succeeded", "failed"):
            if time.monotonic() > deadline:
                raise TimeoutError(f"adjustment {adjustment['id']} of job {job_id} still {adjustment['status']}")
            time.sleep(0.25)
            adjustment = self._json(self.http.get(adjustment["link"]))
        return adjustment

    def status(self, job_id: str) -> dict[str, Any]:
        return self._json(self.http.get(f"/jobs/{job_id}"))

    def cancel(self, job_id: str) -> dict[str, Any]:
        return self._json(self.http.delete(f"/jobs/{job_id}"))

    def wait(self, job_id: str, on_progress: Callable[[dict[str, Any]], None] | None = None,
             timeout_s: float | None = None) -> dict[str, Any]:
        """Follow the job's server-sent events until it ends; returns the final job (any end status).
        A dropped stream is reopened; ``TimeoutError`` after ``timeout_s``."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            remaining = None if deadline is None else max(0.1, deadline - time.monotonic())
            try:
                for job in self._events(job_id, remaining):
                    if on_progress is not None:
                        on_progress(job)
                    if job["status"] in TERMINAL:
                        return job
            except (httpx.TransportError, httpx.TimeoutException):
                pass
            job = self.status(job_id)
            if job["status"] in TERMINAL:
                return job
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(f"job {job_id} still {job['status']} after {timeout_s} s")

    def download(self, job_id: str, name: str = "result.glb", to: str | Path | None = None) -> bytes:
        """``result.glb``, ``report.json`` or ``preview.png`` of a succeeded job; also written to ``to``. A job
        whose ``links.downloads`` is ``redirect`` answers 307: the file is fetched from that presigned URL,
        without the API key (the URL carries its own signature, and the store is not the API)."""
        answer = self.http.get(f"/jobs/{job_id}/{name}")
        if answer.status_code == 307:
            request = self.http.build_request("GET", answer.headers["location"])
            request.headers.pop("Authorization", None)
            answer = self.http.send(request)
        if answer.status_code != 200:
            self._json(answer)
        if to is not None:
            Path(to).write_bytes(answer.content)
        return answer.content

    def _events(self, job_id: str, timeout_s: float | None) -> Iterator[dict[str, Any]]:
        timeout = httpx.Timeout(self.http.timeout.connect, read=timeout_s)
        with self.http.stream("GET", f"/jobs/{job_id}/events", timeout=timeout) as stream:
            if stream.status_code != 200:
                stream.read()
                self._json(stream)
            for line in stream.iter_lines():
                if line.startswith("data: "):
                    yield json.loads(line.removeprefix("data: "))

    @staticmethod
    def _json(answer: httpx.Response) -> dict[str, Any]:
        body = answer.json() if answer.headers.get("content-type", "").startswith("application/json") else {}
        if answer.status_code >= 400:
            error = body.get("error") or {"code": "http_error", "message": answer.text[:200]}
            raise ServiceError(answer.status_code, error.get("code", "http_error"), error.get("message", ""),
                               error.get("field"), retry_after(answer))
        return body


def _webhook(url: str | None, events: Sequence[str] | None) -> dict[str, str | None]:
    return {"webhook": url, "webhook_events": ",".join(events) if events is not None else None}


def _with_queue(options: dict[str, Any] | None, queue: str | None) -> dict[str, Any] | None:
    return options if queue is None else {**(options or {}), "queue": queue}


def _file(item: MeshInput) -> tuple[str, bytes]:
    if isinstance(item, tuple):
        return item
    path = Path(item)
    return path.name, path.read_bytes()
