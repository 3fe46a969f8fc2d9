"""``POST /plans/read`` and ``POST /scenes`` against a real Redis, uvicorn and ``ctp worker``: a description read
into a plan without a job, its refusals (422 with the reader's code), and a described scene placed as one job with
per-stage progress and every relation judged again on the final scene."""

from __future__ import annotations

import json

import pytest

from ctp_core.io import load_objects
from tests.conftest import service_env, wait_for
from tests.test_assemble import GEOMETRY_ONLY
from tests.test_compose import _bench, _box

ALPHA = {"Authorization": "Bearer alpha"}
DESCRIPTION = "put the toolbox on the workbench; a stool to its left"


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "scn", api_keys="alpha", max_stages=4, max_active_jobs=5)


@pytest.fixture(scope="module")
def parts():
    meshes = {"workbench": _bench(), "toolbox": _box(0.45, 0.25, 0.2), "stool": _box(0.5, 0.45, 0.35)}
    return [("object", (f"{name}.glb", mesh.export(file_type="glb"))) for name, mesh in meshes.items()]


def test_a_description_reads_into_a_plan_without_a_job(api):
    answer = api.client.post("/plans/read", json={"prompt": DESCRIPTION, "names": ["workbench", "toolbox", "stool"]},
                             headers=ALPHA)
    assert answer.status_code == 200, answer.text
    plan = answer.json()
    assert plan["base"] == "workbench" and plan["warnings"] == []
    assert [(s["name"], s["relation"], s["on"]) for s in plan["steps"]] == [
        ("toolbox", "on", ["workbench"]), ("stool", "left", ["workbench"])]
    assert [s["support"] for s in plan["steps"]] == ["workbench", "floor"] and plan["reader"] == "rules"


def test_the_plan_read_shows_supports_other_relations_and_warnings_on_their_steps(api):
    answer = api.client.post("/plans/read", json={
        "prompt": "the mug on the tray in the middle of the workbench, and the stool next to it",
        "names": ["mug", "tray", "workbench", "stool", "lamp"]}, headers=ALPHA)
    assert answer.status_code == 200, answer.text
    plan = answer.json()
    assert plan["base"] == "workbench" and plan["base_support"] == "floor"  # what supports the others stays put
    steps = {s["name"]: s for s in plan["steps"]}
    assert (steps["tray"]["on"], steps["tray"]["support"]) == (["workbench"], "workbench")
    assert (steps["mug"]["on"], steps["mug"]["support"]) == (["tray"], "tray")
    assert steps["lamp"]["floor"] and steps["lamp"]["warnings"] == plan["warnings"] == [
        "the lamp is not named in the description: on the floor beside the workbench"]


@pytest.mark.parametrize(("body", "status", "code"), [
    ({"prompt": "a metronome on the workbench", "names": ["workbench", "stool"]}, 422, "unknown_object"),
    ({"prompt": "a stool on the bench; the bench on the stool", "names": ["bench", "stool"]}, 422, "placement_cycle"),
    ({"prompt": "a stool near the bench", "names": ["bench"]}, 400, "invalid_request"),
])
def test_a_description_that_cannot_be_read_is_a_4xx_with_a_code(api, body, status, code):
    answer = api.client.post("/plans/read", json=body, headers=ALPHA)
    assert answer.status_code == status, answer.text
    error = answer.json()["error"]
    assert error["code"] == code and error["message"]


def test_a_scene_naming_an_object_with_no_upload_is_refused_before_queueing(api, parts):
    answer = api.client.post("/scenes", files=parts[:2], data={"prompt": "a metronome on the workbench"},
                             headers=ALPHA)
    assert answer.status_code == 422, answer.text
    assert answer.json()["error"]["code"] == "unknown_object" and "metronome" in answer.json()["error"]["message"]
    names = api.client.post("/scenes", files=parts[:2], data={"prompt": DESCRIPTION, "names": '["a"]'},
                            headers=ALPHA)
    assert (names.status_code, names.json()["error"]["code"], names.json()["error"]["field"]) == (
        400, "invalid_field", "names")
    assert api.client.get("/jobs", headers=ALPHA).json()["total"] == 0


def test_a_described_scene_is_one_job_with_stage_progress(api, worker, parts, tmp_path):
    accepted = api.client.post("/scenes", files=parts, data={"prompt": DESCRIPTION,
                                                             "options": json.dumps(GEOMETRY_ONLY)}, headers=ALPHA)
    assert accepted.status_code == 202, accepted.text
    job_id = accepted.json()["id"]
    events = []
    with api.client.stream("GET", f"/jobs/{job_id}/events", headers=ALPHA, timeout=180) as stream:
        for line in stream.iter_lines():
            if line.startswith("data: "):
                events.append(json.loads(line.removeprefix("data: ")))
    assert events[-1]["status"] == "succeeded", events[-1]
    assert (events[-1]["kind"], events[-1]["description"]) == ("assemble", DESCRIPTION)  # labelled by its sentence
    messages = [e["progress"]["message"] for e in events]
    assert any(m.startswith('stage 2/2: "a stool to the left of the workbench"') for m in messages), messages
    whole = api.client.get(f"/jobs/{job_id}/report.json", headers=ALPHA).json()["whole"]
    assert [(r["name"], r["relation"], r["holds"]) for r in whole["relations"]] == [
        ("toolbox", "on", True), ("stool", "left", True)]
    assert whole["none_intersect"]
    glb = tmp_path / "scene.glb"
    glb.write_bytes(api.client.get(f"/jobs/{job_id}/result.glb", headers=ALPHA).content)
    assert list(load_objects(glb).geometry) == ["workbench", "toolbox", "stool"]


def test_copies_of_the_base_are_read_from_its_one_part(api, worker, tmp_path):
    """"two tables with a lamp on each": the base's part is also the second table's source (read once)."""
    files = [("object", ("table.glb", _bench(0.8, 0.72, 0.6).export(file_type="glb"))),
             ("object", ("lamp.glb", _box(0.2, 0.45, 0.2).export(file_type="glb")))]
    accepted = api.client.post("/scenes", files=files, data={"prompt": "two tables with a lamp on each",
                                                             "options": json.dumps(GEOMETRY_ONLY)}, headers=ALPHA)
    assert accepted.status_code == 202, accepted.text
    job_id = accepted.json()["id"]
    done = wait_for(lambda: (j := api.client.get(f"/jobs/{job_id}", headers=ALPHA).json())["status"]
                    in ("succeeded", "failed") and j, 180, "the job")
    assert done["status"] == "succeeded", done
    glb = tmp_path / "tables.glb"
    glb.write_bytes(api.client.get(f"/jobs/{job_id}/result.glb", headers=ALPHA).content)
    assert list(load_objects(glb).geometry) == ["table_1", "table_2", "lamp_1", "lamp_2"]
    whole = api.client.get(f"/jobs/{job_id}/report.json", headers=ALPHA).json()["whole"]
    assert [(r["name"], r["on"]) for r in whole["relations"]] == [
        ("table_2", ["table_1"]), ("lamp_1", ["table_1"]), ("lamp_2", ["table_2"])]


@pytest.mark.parametrize("names", [["anvil", "gizmo"], '["anvil", "gizmo"]'], ids=["repeated parts", "a JSON list"])
def test_names_are_one_part_each_or_a_json_list(api, parts, names):
    """Both forms name the parts: the description reads over those names (here to a cycle, so nothing is queued;
    over the file names it would name no object)."""
    answer = api.client.post("/scenes", files=parts[:2], headers=ALPHA, data={
        "prompt": "a gizmo on the anvil; the anvil on the gizmo", "names": names})
    assert (answer.status_code, answer.json()["error"]["code"]) == (422, "placement_cycle"), answer.text


@pytest.mark.parametrize("names", ['["anvil", "gizmo"', '["anvil"]', ["anvil", "gizmo", "vice"], '{"a": 1}'],
                         ids=["malformed", "one short", "one over", "not a list"])
def test_a_names_list_that_does_not_fit_is_400_invalid_field(api, parts, names):
    answer = api.client.post("/scenes", files=parts[:2], headers=ALPHA, data={"prompt": DESCRIPTION, "names": names})
    assert (answer.status_code, answer.json()["error"]["code"], answer.json()["error"]["field"]) == (
        400, "invalid_field", "names"), answer.text
