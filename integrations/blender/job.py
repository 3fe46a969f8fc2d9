"""One placement job on the service, submitted and followed in a thread: Blender's UI thread never waits on the
network, and the modal operator only reads ``Job``'s fields on its timer. No ``bpy`` here."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path
from typing import Any

from .client import Client, ServiceError

POLL_S = 0.5
TERMINAL = ("succeeded", "failed", "canceled")


class Job(threading.Thread):
    """Submits ``target``/``source`` (GLB files in ``folder``, removed at the end) with ``fields`` and follows the job
    until it ends or ``cancel()`` is called. Read ``message``, ``fraction``; once ``ended``: ``report`` (succeeded),
    ``error`` (in words), or ``canceled``."""

    def __init__(self, client: Client, folder: Path, target: Path, source: Path, fields: dict[str, str]):
        super().__init__(daemon=True, name="ctp-job")
        self.client, self.folder, self.files, self.fields = client, folder, (target, source), fields
        client.on_wait = self._say
        self.job_id: str | None = None
        self.message, self.fraction = "uploading", 0.0
        self.report: dict[str, Any] | None = None
        self.error: str | None = None
        self.canceled = False
        self.ended = threading.Event()
        self._cancel = threading.Event()

    def cancel(self) -> None:
        """Asks the thread to send ``DELETE /jobs/{id}`` (at once, or as soon as the submit has answered)."""
        self._cancel.set()

    def run(self) -> None:
        try:
            self._follow()
        except ServiceError as exc:  # a refused upload is named by its object, not by the file sent
            named = self.fields.get(f"{exc.field}_name") if exc.field in ("target", "source") else None
            self.error = f"{named}: {exc}" if named else str(exc)
        except Exception as exc:  # shown as one line in the panel, never a traceback
            self.error = f"{type(exc).__name__}: {exc}"
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.ended.set()

    def _follow(self) -> None:
        job = self.client.submit(*self.files, self.fields)
        self.job_id = job["id"]
        while job["status"] not in TERMINAL:
            if self._cancel.is_set():
                self.client.cancel(self.job_id)
                self.canceled, self.message = True, "canceled"
                return
            self._cancel.wait(POLL_S)
            if not self._cancel.is_set():
                job = self.client.status(self.job_id)
                progress = job.get("progress") or {}
                self._say(progress.get("message") or job["status"], progress.get("fraction"))
        if job["status"] == "succeeded":
            self.report = self.client.report(self.job_id)
            self._say("done", 1.0)
        elif job["status"] == "canceled":
            self.canceled, self.message = True, "canceled on the service"
        else:
            error = job.get("error") or {}
            self.error = f"the job failed: {error.get('message', 'no reason given')} ({error.get('code', 'failed')})"

    def _say(self, message: str, fraction: float | None = None) -> None:
        self.message = message
        if fraction is not None:
            self.fraction = float(fraction)
