"""What the add-on adds to a placement: its round trip (export, submit, wait, apply) against the same job sent with
curl, on a pair of about 50k triangles (the objects' Subdivision modifiers evaluated on export)."""

import json
import subprocess
import time
from pathlib import Path

import bpy
from conftest import MEASURES, make_cup, make_table, place, read_glb, select

POLL_S = 0.5  # as the add-on polls (job.POLL_S), so both round trips wait alike


def subdivided(obj: bpy.types.Object, levels: int) -> None:
    modifier = obj.modifiers.new("Subdivision", "SUBSURF")
    modifier.subdivision_type, modifier.levels = "SIMPLE", levels  # more faces, the same shape


def triangles(path: Path) -> int:
    gltf = read_glb(path)
    return sum(gltf["accessors"][p["indices"]]["count"] // 3 for m in gltf["meshes"] for p in m["primitives"])


def curl_round_trip(url: str, folder: Path, fields: dict[str, str]) -> dict:
    """The job through plain HTTP: submit the two files, poll its status, fetch its report."""
    form = [f"-Ftarget=@{folder / 'target.glb'}", f"-Fsource=@{folder / 'source.glb'}"]
    form += [f"-F{name}={value}" for name, value in fields.items()]
    job = json.loads(subprocess.run(["curl", "-sf", *form, f"{url}/align"], capture_output=True, check=True).stdout)
    while job["status"] not in ("succeeded", "failed", "canceled"):
        time.sleep(POLL_S)
        job = json.loads(subprocess.run(["curl", "-sf", f"{url}/jobs/{job['id']}"], capture_output=True,
                                        check=True).stdout)
    assert job["status"] == "succeeded", job
    return json.loads(subprocess.run(["curl", "-sf", f"{url}/jobs/{job['id']}/report.json"], capture_output=True,
                                     check=True).stdout)


def test_blender_overhead_of_export_and_apply(scene, addon, service, tmp_path):
    """Export and apply timed alone (the overhead); the round trips for context: curl before and after the add-on's,
    as the worker's first job of a session is slower than the next."""
    table, cup = make_table(), make_cup(segments=80)
    subdivided(table, 4)
    subdivided(cup, 3)
    select(table, cup)
    started = time.perf_counter()
    frame = addon.scene.export_pair(bpy.context, table, cup, tmp_path)
    export_s = time.perf_counter() - started
    faces = triangles(tmp_path / "target.glb") + triangles(tmp_path / "source.glb")
    fields = {"prompt": "a cup on the table", "target_name": "Table", "source_name": "Cup",
              "options": json.dumps({"preset": "test"})}

    curl_s = [timed(curl_round_trip, service, tmp_path, fields)[0]]
    addon_s, finished = timed(place, "a cup on the table")
    assert finished == {"FINISHED"}
    seconds, report = timed(curl_round_trip, service, tmp_path, fields)
    curl_s.append(seconds)
    apply_s, _ = timed(addon.scene.apply_result, scene, cup, frame, report)

    MEASURES.append(f"blender: {faces} triangles; export {1000 * export_s:.0f} ms + apply {1000 * apply_s:.1f} ms; "
                    f"round trip with the add-on {addon_s:.2f} s, with curl {curl_s[0]:.2f} s before it and "
                    f"{curl_s[1]:.2f} s after it")
    assert 45_000 < faces < 60_000
    assert export_s + apply_s <= 1.0


def timed(function, *args):
    started = time.perf_counter()
    value = function(*args)
    return time.perf_counter() - started, value
