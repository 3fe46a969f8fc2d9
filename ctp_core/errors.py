"""Typed errors with stable machine-readable codes.

The service maps ``CtpError.code`` to HTTP 4xx bodies and the CLI prints ``code: message`` and exits
non-zero; neither ever shows a traceback for these.
"""

from __future__ import annotations


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
