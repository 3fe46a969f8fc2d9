"""Bounded loading (``ctp_core.io.loader``): a load past its wall time or memory ends ``mesh_too_complex``
and its process is replaced; closing the loader ends a load in flight at once."""

from __future__ import annotations

import json
import struct
import threading
import time

import numpy as np
import pytest

from ctp_core.errors import MeshError
from ctp_core.io import MeshLimits
from ctp_core.io.loader import LoaderUnavailable, MeshLoader
from tests.test_service import BOX, deep_chain_glb, grid_mesh, ply

WIDE = MeshLimits(max_nodes=10**6)


def wide_glb(leaves: int) -> bytes:
    """One triangle instanced under ``leaves`` sibling nodes: within a raised node budget, slow to flatten."""
    triangle = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    nodes = [{"children": list(range(1, leaves + 1))}] + [{"mesh": 0, "translation": [0, k, 0]} for k in range(leaves)]
    tree = json.dumps({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": nodes,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "buffers": [{"byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
    }).encode()
    tree += b" " * (-len(tree) % 4)
    body = struct.pack("<I4s", len(tree), b"JSON") + tree + struct.pack("<I4s", 36, b"BIN\0") + triangle
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


@pytest.fixture(scope="module")
def loader():
    with MeshLoader(1, timeout_s=1.0) as pool:
        yield pool


def _code(call) -> tuple[str, float]:
    """The refusal's code and how long it took."""
    started = time.monotonic()
    with pytest.raises(MeshError) as info:
        call()
    return info.value.code, time.monotonic() - started


def test_loads_in_a_child_and_reuses_it(loader):
    assert loader.load(BOX, filename="box.glb", name="box").faces.shape == (12, 3)
    started = time.monotonic()
    assert loader.check(BOX, "box.glb", MeshLimits()) == 12
    assert time.monotonic() - started < 0.5  # no new process: the started one serves again


def test_deep_chain_is_refused_from_the_json(loader):
    code, seconds = _code(lambda: loader.load(deep_chain_glb(5000), filename="deep.glb"))
    assert code == "mesh_too_complex" and seconds < 1.0


def test_wall_time_limit_kills_and_replaces_the_child(loader):
    code, seconds = _code(lambda: loader.load(wide_glb(60_000), filename="wide.glb", limits=WIDE))
    assert code == "mesh_too_complex" and 1.0 <= seconds < 10.0  # 1 s, plus a busy machine's slack
    assert loader.load(BOX, filename="box.glb").faces.shape == (12, 3)  # a fresh child took its place


def test_memory_limit():
    vertices, faces = grid_mesh(500)  # 498k faces: fits the face budget, not 600 MiB of address space
    with MeshLoader(1, timeout_s=60.0, memory_bytes=600 * 2**20) as pool:
        with pytest.raises(MeshError, match="memory limit") as info:
            pool.load(ply(vertices + np.float32(0.5), faces), filename="grid.ply")
        assert info.value.code == "mesh_too_complex"
        assert pool.load(BOX, filename="box.glb").faces.shape == (12, 3)


def test_close_ends_a_load_in_flight():
    pool = MeshLoader(1, timeout_s=60.0)
    pool.load(BOX, filename="box.glb")
    errors = []

    def slow():
        try:
            pool.load(wide_glb(200_000), filename="wide.glb", limits=WIDE)
        except Exception as exc:  # noqa: BLE001 - recorded and checked below
            errors.append(exc)

    thread = threading.Thread(target=slow)
    thread.start()
    time.sleep(0.5)
    started = time.monotonic()
    pool.close()
    thread.join(timeout=5)
    assert not thread.is_alive() and time.monotonic() - started < 5
    assert isinstance(errors[0], LoaderUnavailable)
    with pytest.raises(LoaderUnavailable):
        pool.load(BOX, filename="box.glb")


def test_a_relative_path_is_read_from_the_callers_folder(loader, tmp_path, monkeypatch):
    """The loading processes run elsewhere (the package root): `ctp align try/table.glb` must still work."""
    (tmp_path / "try").mkdir()
    (tmp_path / "try" / "box.glb").write_bytes(BOX)
    monkeypatch.chdir(tmp_path)
    assert len(loader.load("try/box.glb").faces) == 12
