"""Real Blender (the ``bpy`` module, headless) with the add-on installed from its extension zip, against a real
``ctp serve`` started from the project's venv (``CTP_BIN``, default ``.venv/bin/ctp``) on a free port.

Runs in its own venv (``make test-blender``: bpy pins numpy<2, which the project's venv cannot have); nothing
of ctp is importable here, so the service is reached over HTTP only, as the add-on reaches it.
"""

import atexit
import importlib
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

# Blender's user folders (its extensions among them) in a temporary folder, before bpy starts: the add-on is
# installed there, never into the user's own Blender
os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="ctp-blender-user-")
atexit.register(shutil.rmtree, os.environ["BLENDER_USER_RESOURCES"], True)

import bpy  # noqa: E402 - first: it makes bmesh and mathutils importable

# isort: split
import bmesh  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
CTP_BIN = Path(os.environ.get("CTP_BIN", REPO / ".venv" / "bin" / "ctp"))
MEASURES: list[str] = []  # lines for the end of the run (the round trips of test_blender_overhead)
TABLE_TOP = 0.75  # the top's upper face, world z


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pytest_terminal_summary(terminalreporter) -> None:
    for line in MEASURES:
        terminalreporter.write_line(line)


@pytest.fixture(scope="session")
def addon():
    """The extension zip as ``make blender-addon`` builds it, installed and enabled the way a user installs it
    from disk; the add-on's package."""
    subprocess.run(["make", "-s", "blender-addon"], cwd=REPO, check=True)
    manifest = (REPO / "integrations" / "blender" / "blender_manifest.toml").read_text()
    version = next(line.split('"')[1] for line in manifest.splitlines() if line.startswith("version"))
    archive = REPO / "dist" / f"ctp_place-{version}.zip"
    assert bpy.ops.extensions.package_install_files(filepath=str(archive), repo="user_default",
                                                    enable_on_install=True) == {"FINISHED"}
    return importlib.import_module("bl_ext.user_default.ctp_place")


@pytest.fixture(scope="session")
def service(tmp_path_factory):
    """``ctp serve`` (embedded Redis, one worker) with the tiny random model, on a free port; its URL."""
    if not CTP_BIN.is_file():
        pytest.fail(f"no ctp at {CTP_BIN}: run `make install` first, or set CTP_BIN")
    home = tmp_path_factory.mktemp("serve")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("CTP_", "BLENDER_")) and k != "REDIS_URL"}
    env.update(CTP_MODEL="random:tiny", CTP_THREADS="1", CTP_RUNTIME="torch", CTP_LOG_LEVEL="WARNING",
               CTP_HEARTBEAT_S="0.5", CTP_PROGRESS_EVERY_S="0.5", XDG_CACHE_HOME=str(home / "cache"),
               HF_HOME=str(home / "hf"), HF_HUB_OFFLINE="1", OMP_WAIT_POLICY="PASSIVE", OMP_NUM_THREADS="1")
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with open(home / "serve.log", "wb") as log:
        serve = subprocess.Popen([str(CTP_BIN), "serve", "--port", str(port)], env=env, stdout=log,
                                 stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + 120
            while not ready(url):
                if serve.poll() is not None or time.monotonic() > deadline:
                    pytest.fail(f"ctp serve did not become ready: {(home / 'serve.log').read_text()[-2000:]}")
                time.sleep(0.5)
            yield url
        finally:
            serve.send_signal(signal.SIGTERM)
            try:
                serve.wait(timeout=40)
            except subprocess.TimeoutExpired:
                serve.kill()
                serve.wait()


def ready(url: str) -> bool:
    try:
        with urllib.request.urlopen(f"{url}/readyz", timeout=2) as answer:
            return answer.status == 200
    except (urllib.error.URLError, ConnectionError, TimeoutError):
        return False


@pytest.fixture
def scene(addon, service):
    """An empty scene, the add-on pointed at the service, no job state left from another test."""
    bpy.ops.wm.read_homefile(use_empty=True)
    preferences = bpy.context.preferences.addons[addon.__name__].preferences
    preferences.url, preferences.api_key = service, ""
    state = bpy.context.window_manager.ctp_job
    state.message, state.fraction, state.error = "", 0.0, ""
    return bpy.context.scene


def box(mesh: bmesh.types.BMesh, centre: tuple[float, float, float], size: tuple[float, float, float]) -> None:
    bmesh.ops.create_cube(mesh, size=1.0, matrix=Matrix.LocRotScale(Vector(centre), None, Vector(size)))


def new_object(name: str, mesh: bmesh.types.BMesh, material: tuple[float, float, float, float]) -> bpy.types.Object:
    """A mesh object in the scene's collection, with one material of that colour on its mesh."""
    data = bpy.data.meshes.new(name)
    mesh.to_mesh(data)
    mesh.free()
    paint = bpy.data.materials.new(f"{name} paint")
    paint.diffuse_color = material
    data.materials.append(paint)
    obj = bpy.data.objects.new(name, data)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def make_table(location=(1.0, 2.0, 0.0), turn_z: float = 0.6) -> bpy.types.Object:
    """A table in Blender's Z-up: a 1.2 x 0.8 m top whose upper face is at ``TABLE_TOP`` over four legs, its origin
    on the floor, turned about Z and away from the origin."""
    mesh = bmesh.new()
    box(mesh, (0, 0, TABLE_TOP - 0.025), (1.2, 0.8, 0.05))
    for x in (-0.55, 0.55):
        for y in (-0.35, 0.35):
            box(mesh, (x, y, (TABLE_TOP - 0.05) / 2), (0.05, 0.05, TABLE_TOP - 0.05))
    table = new_object("Table", mesh, (0.55, 0.35, 0.2, 1.0))
    table.location, table.rotation_euler = location, (0.0, 0.0, turn_z)
    return table


def make_cup(location=(4.0, -3.0, 1.5), rotation=(0.5, 0.3, 1.2), segments: int = 32) -> bpy.types.Object:
    """A cup (a closed cylinder 8 cm across, 10 cm high, its origin at its base's centre), far from the table and
    turned; a Bevel modifier, so the export has to use the evaluated mesh."""
    mesh = bmesh.new()
    bmesh.ops.create_cone(mesh, cap_ends=True, segments=segments, radius1=0.04, radius2=0.04, depth=0.1,
                          matrix=Matrix.Translation((0, 0, 0.05)))
    cup = new_object("Cup", mesh, (0.1, 0.3, 0.8, 1.0))
    cup.modifiers.new("Bevel", "BEVEL").width = 0.004
    cup.location, cup.rotation_euler = location, rotation
    return cup


def select(target: bpy.types.Object, source: bpy.types.Object) -> None:
    """As a user does it: the source selected, the target selected and active."""
    bpy.context.view_layer.update()  # objects just linked get their view layer bases first
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in (target, source))
    bpy.context.view_layer.objects.active = target
    bpy.context.view_layer.update()


def world_box(obj: bpy.types.Object) -> tuple[Vector, Vector]:
    """The object's evaluated mesh's bounds in world coordinates."""
    bpy.context.view_layer.update()
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    points = [evaluated.matrix_world @ v.co for v in evaluated.data.vertices]
    return (Vector([min(p[i] for p in points) for i in range(3)]),
            Vector([max(p[i] for p in points) for i in range(3)]))


def on_table_top(cup: bpy.types.Object, table: bpy.types.Object) -> None:
    """The cup's base on the table's top (within 1.5 cm: the service's contact is within its sample spacing) and
    its centre over the top, in the table's own axes."""
    low, high = world_box(cup)
    assert abs(low.z - TABLE_TOP) < 0.015, (low.z, TABLE_TOP)
    centre = table.matrix_world.inverted() @ ((low + high) / 2)
    assert abs(centre.x) < 0.6 and abs(centre.y) < 0.4, centre


def upright(obj: bpy.types.Object) -> float:
    """How closely the object's own +Z points up in the world (1: upright)."""
    return (obj.matrix_world.to_3x3() @ Vector((0, 0, 1))).normalized().z


def place(prompt: str, preset: str = "test", count: int = 0) -> set[str]:
    """The Place button as a script presses it: execute (background mode has no modal loop), undo step pushed."""
    settings = bpy.context.scene.ctp
    settings.prompt, settings.preset, settings.count = prompt, preset, count
    return bpy.ops.ctp.place("EXEC_DEFAULT", True)


def read_glb(path: Path) -> dict:
    """The JSON chunk of a GLB (glTF 2.0 binary: a 12-byte header, then the JSON chunk's length and type)."""
    data = path.read_bytes()
    (length,) = struct.unpack_from("<I", data, 12)
    return json.loads(data[20:20 + length])
