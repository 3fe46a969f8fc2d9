"""Write the API's OpenAPI schema as YAML: ``python -m service.openapi > openapi.yaml``.

``openapi.yaml`` at the repository root is the committed contract; a test fails when the served
schema drifts from it, so regenerate it with this command whenever the API changes.
"""

from __future__ import annotations

import sys

import yaml

from service.app import create_app
from service.settings import Settings


def schema_yaml() -> str:
    """The schema does not depend on settings; the URL is never connected to."""
    app = create_app(Settings(redis_url="redis://127.0.0.1:1/0", api_keys=[], cors_origins=[]))
    return yaml.safe_dump(app.openapi(), sort_keys=False, allow_unicode=True, width=110)


if __name__ == "__main__":
    sys.stdout.write(schema_yaml())
