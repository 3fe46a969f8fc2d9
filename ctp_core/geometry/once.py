"""What a scene's steps ask of the same object again, made once and kept while the scene is placed.

A scene is placed step by step (``assembly.assemble``), and every step prepares its pair afresh
(``pairs.prepare_pair``), as does every check of a candidate and the final judgement (``adjust.adjust`` through
``assembly.whole``): each time, every placed object is copied into the scene frame, its winding fixed, its
surface sampled, its render arrays made and its up and front found again, though the object has not moved and
the answer is the same each time. ``scene()`` opens a store for the length of a scene; ``per_mesh`` functions
keep their answers in it, keyed by the mesh (its identity and its content's hash, so a mesh changed in place is
never answered from an older copy) and their other arguments; ``per_content`` functions, which read nothing of a
mesh but its content, by its content's hash alone (copies of one object ask once). The answer kept is the very one
a fresh call gives (the same function of the same inputs), so nothing placed or judged changes; outside a scene
nothing is kept.

What is kept is shared: a caller must not change it (a mesh kept here is copied before it is changed, as
``pairs.outward`` does).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, TypeVar

import trimesh

__all__ = ["per_content", "per_mesh", "scene", "value"]

_STORE: ContextVar[dict[Hashable, tuple[Any, Any]] | None] = ContextVar("once", default=None)

Kept = TypeVar("Kept")


@contextmanager
def scene() -> Iterator[None]:
    """Keep what ``per_mesh`` functions and ``value`` make until the block ends (a block inside another keeps in
    the outer one's store); everything kept is let go at its end."""
    if _STORE.get() is not None:
        yield
        return
    token = _STORE.set({})
    try:
        yield
    finally:
        _STORE.reset(token)


def per_mesh(build: Callable[..., Kept]) -> Callable[..., Kept]:
    """``build(mesh, *args)`` kept within a ``scene`` per mesh and ``args`` (hashable); called as it is outside
    one."""

    @functools.wraps(build)
    def kept(mesh: trimesh.Trimesh, *args: Hashable) -> Kept:
        if _STORE.get() is None:
            return build(mesh, *args)
        return value((build.__module__, build.__qualname__, id(mesh), hash(mesh), args),
                     lambda: build(mesh, *args), pin=mesh)

    return kept


def per_content(build: Callable[[trimesh.Trimesh], Kept]) -> Callable[[trimesh.Trimesh], Kept]:
    """``build(mesh)`` kept within a ``scene`` per the mesh's content (its hash: no identity, nothing pinned), for a
    ``build`` that reads nothing else of it; called as it is outside one."""

    @functools.wraps(build)
    def kept(mesh: trimesh.Trimesh) -> Kept:
        if _STORE.get() is None:
            return build(mesh)
        return value((build.__module__, build.__qualname__, hash(mesh)), lambda: build(mesh))

    return kept


def value(key: Hashable, build: Callable[[], Kept], *, pin: object = None) -> Kept:
    """``build()`` kept within a ``scene`` under ``key``: a key naming objects by identity must ``pin`` them (they
    are held as long as the answer is, so no other object takes their identity). Outside a scene, ``build()``."""
    store = _STORE.get()
    if store is None:
        return build()
    hit = store.get(key)
    if hit is None:
        hit = store[key] = (pin, build())
    return hit[1]
