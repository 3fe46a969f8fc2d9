"""Structured logs: one JSON object per line, with the job id and friends as fields.

Call sites pass context through ``extra`` (``log.info("job queued", extra={"job_id": ...})``) so a log
pipeline can filter one job across the API and every worker.
"""

from __future__ import annotations

import json
import logging
from datetime import UTC, datetime

CONTEXT_FIELDS = ("job_id", "owner", "worker", "status", "code", "method", "path", "duration_ms", "http_status")


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        entry = {
            "ts": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname.lower(),
            "logger": record.name,
            "msg": record.getMessage(),
        }
        entry.update({k: getattr(record, k) for k in CONTEXT_FIELDS if getattr(record, k, None) is not None})
        if record.exc_info:
            entry["exc"] = self.formatException(record.exc_info)
        return json.dumps(entry, default=str)


def configure(level: str) -> None:
    """JSON lines on stderr for our loggers and rq's; idempotent."""
    handler = logging.StreamHandler()
    handler.setFormatter(JsonFormatter())
    for name in ("ctp", "rq.worker", "rq.job"):
        logger = logging.getLogger(name)
        logger.handlers[:] = [handler]
        logger.setLevel(level.upper())
        logger.propagate = False
