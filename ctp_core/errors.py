"""Typed errors with stable machine-readable codes.

The service maps ``CtpError.code`` to HTTP 4xx bodies and the CLI prints ``code: message`` and exits
non-zero; neither ever shows a traceback for these.
"""

from __future__ import annotations

import re
import traceback


class CtpError(Exception):
    """Base class: ``code`` is stable API, ``message`` is for humans, ``field`` names the input."""

    code = "ctp_error"

    def __init__(self, message: str, *, code: str | None = None, field: str | None = None):
        super().__init__(message)
        self.message = message
        if code is not None:
            self.code = code
        self.field = field

    def to_dict(self) -> dict:
        return {"code": self.code, "message": self.message, "field": self.field}


class MeshError(CtpError):
    """A mesh upload was refused. Codes: mesh_empty, mesh_too_large, mesh_file_too_large,
    mesh_external_reference, mesh_unreadable, mesh_invalid_values, mesh_unknown_format, mesh_zip_invalid."""

    code = "mesh_unreadable"


class ImageError(CtpError):
    """A reference picture was refused. Codes: invalid_image, image_too_large."""

    code = "invalid_image"


class ModelError(CtpError):
    """A vision-language model could not be loaded (bad spec, missing weights offline)."""

    code = "model_unavailable"


class ConfigError(CtpError):
    """An option is out of range or unknown."""

    code = "invalid_option"


class ModelSpecError(ModelError, ConfigError):
    """A model spec that names no model (malformed, unknown backend or architecture): bad usage, not an
    unavailable model, so the CLI exits 2 for it."""

    code = "invalid_option"


class Canceled(CtpError):
    """The run was cancelled between steps."""

    code = "canceled"


class JobTooLarge(CtpError):
    """A run needed more memory than it may have (the worker's per-job ceiling, ``CTP_JOB_MEMORY_MB``, or
    the machine): an allocation failed. ``JobTooLarge.of`` builds it from that failure."""

    code = "job_too_large"

    @classmethod
    def of(cls, exc: BaseException, *, stage: str | None = None, budget_mb: int | None = None) -> JobTooLarge:
        """The error for ``exc`` (an ``out_of_memory`` failure): which stage, which budget, what failed.

        Only text is kept from ``exc``; the caller drops ``exc`` itself (``forget``) so that the frames its
        traceback holds, and the arrays in them, are freed."""
        budget = (f"more than its memory budget of {budget_mb} MB (CTP_JOB_MEMORY_MB)" if budget_mb
                  else "more memory than it could get")
        during = f" during {stage}" if stage else ""
        return cls(f"the job needed {budget}{during}: {_allocation(exc)}; use smaller meshes (fewer faces) or a "
                   "lighter preset", code=cls.code)


def out_of_memory(exc: BaseException) -> bool:
    """Whether ``exc`` is an allocation failure: Python's or numpy's ``MemoryError``, torch's CPU allocator
    (``RuntimeError: ... DefaultCPUAllocator: can't allocate memory``), ONNX Runtime's arena (``Failed to
    allocate memory``). Under a per-job ``RLIMIT_DATA`` (``worker.memory.job_memory``) all of them raise
    inside the job, so the job fails alone and the process keeps serving."""
    if isinstance(exc, MemoryError):
        return True
    text = str(exc) if isinstance(exc, RuntimeError) or type(exc).__module__.startswith("onnxruntime") else ""
    return any(marker in text for marker in _OUT_OF_MEMORY)


def forget(exc: BaseException) -> None:
    """Drop what ``exc`` keeps alive: the local variables of every frame of its traceback and of its
    chained exceptions (the big arrays a failed allocation left behind)."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        traceback.clear_frames(exc.__traceback__)
        exc.__traceback__ = None
        exc = exc.__cause__ or exc.__context__


_OUT_OF_MEMORY = ("DefaultCPUAllocator: can't allocate memory", "Failed to allocate memory")


def _allocation(exc: BaseException) -> str:
    """What could not be allocated, in a few words (torch's message is a C++ enforce dump)."""
    text = str(exc)
    if match := re.search(r"allocate (\d+) bytes|buffer of size (\d+)", text):  # torch, ONNX Runtime
        size = int(match.group(1) or match.group(2))
        return f"an allocation of {size / 2**30:.2f} GiB failed" if size >= 2**30 else \
            f"an allocation of {size / 2**20:.0f} MiB failed"
    if match := re.search(r"allocate ([\d.]+ [KMGTPE]?i?B)", text):
        return f"an allocation of {match.group(1)} failed"
    return f"an allocation failed ({type(exc).__name__})"
