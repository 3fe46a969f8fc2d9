"""The names objects are sent under: what the user called them, without what Blender or an exporter added."""

from __future__ import annotations

import re

DUPLICATE = re.compile(r"\.\d{3,}$")  # Blender's suffix of a second object of a name: "Cup.001"
GENERIC = re.compile(r"(geometry|mesh|object|node)([ _.]?\d+)?", re.IGNORECASE)  # exporters' default node names


def object_name(name: str, data_name: str = "") -> str | None:
    """An object's name (``name``; where that is an exporter's generic one, e.g. ``geometry_0``, its mesh's name
    ``data_name``) without Blender's ``.001`` suffix, underscores as spaces; None where both are generic (the
    service then names it by its file)."""
    for candidate in (name, data_name):
        plain = DUPLICATE.sub("", candidate).replace("_", " ").strip()
        if plain and not GENERIC.fullmatch(plain):
            return plain
    return None
