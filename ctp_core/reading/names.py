"""Object names: what an object is called when the user does not say, and how long a name may be.

The priors read these names ("coffee cup" is a cup), so the CLI, the service and the Python client must
derive the same name from the same file; this module imports nothing heavy so the client can use it too.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import PurePath

NAME_MAX = 100  # characters of an object's name (the service refuses longer ones)


def default_name(filename: str, fallback: str) -> str:
    """An object's name from its file name ("coffee_cup.glb" -> "coffee cup"), cut to NAME_MAX; ``fallback``
    when nothing is left."""
    return PurePath(filename).stem.replace("_", " ").replace("-", " ").strip()[:NAME_MAX] or fallback


def ground_names(on: str | Sequence[str] | None) -> tuple[str, ...]:
    """The names an ``on`` gives (the placed objects a source relates to): none, one (a name) or several (a list;
    "between" has two)."""
    return () if on is None else (on,) if isinstance(on, str) else tuple(on)
