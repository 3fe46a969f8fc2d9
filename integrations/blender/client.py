"""The ctp service over HTTP with Python's standard library only: inside Blender there is neither httpx nor any of
ctp's packages. Every failure becomes a ``ServiceError`` whose text says what the user can do about it."""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from email.utils import parsedate_to_datetime
from pathlib import Path
from typing import Any

RETRIES = 3  # as service.client: how often a 429 or 503 with a Retry-After is sent again
MAX_WAIT_S = 30.0  # ... while the wait it asks for is at most this
TIMEOUT_S = 60.0


class ServiceError(Exception):
    """A failure in words for the user; ``code`` and ``field`` are the service's where it answered."""

    def __init__(self, message: str, code: str | None = None, field: str | None = None):
        super().__init__(message)
        self.code, self.field = code, field


class _KeepNoKey(urllib.request.HTTPRedirectHandler):
    """Follows a download's redirect (storage with presigned URLs) without the API key: the URL carries its own
    signature, and an object store refuses a request that has both."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        request = super().redirect_request(req, fp, code, msg, headers, newurl)
        if request is not None:
            request.remove_header("Authorization")
        return request


class Client:
    """``on_wait(message)`` is told when a 429 or 503 is waited out, so the panel can say why nothing moves."""

    def __init__(self, url: str, api_key: str = "", *, on_wait: Callable[[str], None] | None = None,
                 timeout_s: float = TIMEOUT_S):
        self.url = url.rstrip("/")
        self.api_key = api_key
        self.on_wait = on_wait
        self.timeout_s = timeout_s
        self.opener = urllib.request.build_opener(_KeepNoKey)

    def submit(self, target: Path, source: Path, fields: dict[str, str]) -> dict[str, Any]:
        """``POST /align`` with the two GLB files and the text fields; the queued job."""
        body, content_type = multipart(fields, {"target": target, "source": source})
        return json.loads(self.request("POST", "/align", body, {"Content-Type": content_type}))

    def status(self, job_id: str) -> dict[str, Any]:
        return json.loads(self.request("GET", f"/jobs/{job_id}"))

    def cancel(self, job_id: str) -> None:
        """``DELETE /jobs/{id}``; a job that already ended (409) is left as it is."""
        try:
            self.request("DELETE", f"/jobs/{job_id}")
        except ServiceError as exc:
            if exc.code != "job_finished":
                raise

    def report(self, job_id: str) -> dict[str, Any]:
        return json.loads(self.request("GET", f"/jobs/{job_id}/report.json"))

    def request(self, method: str, path: str, body: bytes | None = None,
                headers: dict[str, str] | None = None) -> bytes:
        """One call, sent again after the ``Retry-After`` of a 429 or 503 (at most ``RETRIES`` times, while it asks
        for at most ``MAX_WAIT_S``); the answer's body, or ``ServiceError``."""
        headers = dict(headers or {})
        if self.api_key:
            headers["Authorization"] = f"Bearer {self.api_key}"
        attempt = 0
        while True:
            request = urllib.request.Request(self.url + path, data=body, method=method, headers=headers)
            try:
                with self.opener.open(request, timeout=self.timeout_s) as answer:
                    return answer.read()
            except urllib.error.HTTPError as answer:
                wait_s = retry_after(answer)
                error = self._error(answer, wait_s)
                if wait_s is None or wait_s > MAX_WAIT_S or attempt == RETRIES:
                    raise error from None
                if self.on_wait is not None:
                    self.on_wait(f"{error} - trying again in {wait_s:.0f} s")
                time.sleep(wait_s)
                attempt += 1
            except (urllib.error.URLError, ConnectionError) as exc:
                reason = getattr(exc, "reason", exc)
                raise ServiceError(f"no ctp service answers at {self.url} ({reason}): start one with `make serve` "
                                   "in the ctp repository, or set the service URL in the add-on's preferences",
                                   "unreachable") from None
            except TimeoutError:
                raise ServiceError(f"the ctp service at {self.url} did not answer within {self.timeout_s:.0f} s",
                                   "timeout") from None

    def _error(self, answer: urllib.error.HTTPError, wait_s: float | None) -> ServiceError:
        """The service's ``{"error": {code, message, field}}`` as a sentence; 401 says where the key goes."""
        try:
            error = json.loads(answer.read()).get("error") or {}
        except (ValueError, AttributeError):
            error = {}
        code = error.get("code", f"http_{answer.code}")
        message = error.get("message") or f"the service at {self.url} answered {answer.code} {answer.reason}"
        if answer.code == 401:
            what = "refused the API key" if self.api_key else "needs an API key"
            message = f"the service at {self.url} {what} ({message}): set the key in the add-on's preferences"
        else:
            message += f" ({code}" + (f"; the service asks to try again in {wait_s:.0f} s)" if wait_s is not None
                                      else ")")
        return ServiceError(message, code, error.get("field"))


def retry_after(answer: urllib.error.HTTPError) -> float | None:
    """The seconds a 429 or 503 asks to wait (``Retry-After``: seconds or an HTTP date); None otherwise. The rule
    of ``service.client.retry_after``, kept here too: inside Blender the add-on has the standard library only."""
    value = answer.headers.get("Retry-After") if answer.code in (429, 503) else None
    if value is None:
        return None
    if value.strip().isdigit():
        return float(value)
    try:
        return max(0.0, (parsedate_to_datetime(value) - datetime.now(UTC)).total_seconds())
    except (TypeError, ValueError):
        return None


def multipart(fields: dict[str, str], files: dict[str, Path]) -> tuple[bytes, str]:
    """A ``multipart/form-data`` body (urllib has no encoder) and its content type."""
    boundary = uuid.uuid4().hex
    parts = []
    for name, value in fields.items():
        parts.append(f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"\r\n\r\n'.encode()
                     + value.encode() + b"\r\n")
    for name, path in files.items():
        parts.append(f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; filename="{path.name}"\r\n'
                     "Content-Type: model/gltf-binary\r\n\r\n".encode() + path.read_bytes() + b"\r\n")
    return b"".join(parts) + f"--{boundary}--\r\n".encode(), f"multipart/form-data; boundary={boundary}"
