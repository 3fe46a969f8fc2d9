"""``POST /assemble`` and chained ``POST /align`` (``target_job``) against a real Redis, uvicorn and
``ctp worker``: the three-stage table setting end to end (per-stage progress, contacts measured on the
downloaded GLB), the plan's validation before queueing, and chaining on finished, unfinished and
another key's jobs."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from PIL import Image

from ctp_core.io import load_objects
from ctp_core.pairs import objects
from tests.conftest import REPO, service_env, wait_for
from tests.test_assemble import GEOMETRY_ONLY, check_contacts, table_plate_cup
from tests.test_assemble_between import LAMP_PROMPT, check_between, sofa_armchair_lamp

ALPHA, BETA = ({"Authorization": f"Bearer {k}"} for k in ("alpha", "beta"))


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "asm", api_keys="alpha,beta", max_stages=3, max_scene_faces=300,
                       max_active_jobs=20)


@pytest.fixture(scope="module")
def files():
    return {name: mesh.export(file_type="glb") for name, mesh in table_plate_cup().items()}


def post_assembly(api, files, plan, options=GEOMETRY_ONLY, sources=("plate", "cup"), headers=ALPHA):
    parts = [("base", ("table.glb", files["table"]))]
    parts += [("source", (f"{name}.glb", files[name])) for name in sources]
    return api.client.post("/assemble", files=parts, data={"plan": json.dumps(plan), "options": json.dumps(options)},
                           headers=headers)


PLAN = [{"file": "plate.glb", "prompt": "a plate on the table"},
        {"file": "cup.glb", "prompt": "a cup on the plate", "name": "cup", "on": "plate"}]


def finished(api, job_id, headers=ALPHA, timeout_s=180):
    return wait_for(lambda: (j := api.client.get(f"/jobs/{job_id}", headers=headers).json())["status"]
                    in ("succeeded", "failed", "canceled") and j, timeout_s, f"job {job_id}")


@pytest.fixture(scope="module")
def assembled(api, worker, files):
    """The table setting as one job, followed over its event stream; chaining on it while it runs is 409."""
    accepted = post_assembly(api, files, PLAN)
    assert accepted.status_code == 202, accepted.text
    job_id = accepted.json()["id"]
    early = api.client.post("/align", data={"target_job": job_id, "prompt": "a cup on the plate",
                                            "options": json.dumps(GEOMETRY_ONLY)},
                            files={"source": ("cup.glb", files["cup"])}, headers=ALPHA)
    events = []
    with api.client.stream("GET", f"/jobs/{job_id}/events", headers=ALPHA, timeout=180) as stream:
        for line in stream.iter_lines():
            if line.startswith("data: "):
                events.append(json.loads(line.removeprefix("data: ")))
    return job_id, early, events


def test_assembly_runs_as_one_job_with_stage_progress(api, assembled):
    job_id, _, events = assembled
    final = events[-1]
    assert final["status"] == "succeeded", final
    stages = [(e["progress"]["stage"]["index"], e["progress"]["stage"]["count"], e["progress"]["stage"]["label"])
              for e in events if e["progress"]["kind"] in ("phase_start", "step", "phase_end")]
    assert stages[0] == (1, 2, "a plate on the table") and stages[-1] == (2, 2, "a cup on the plate")
    assert stages == sorted(stages)
    assert any(e["progress"]["message"].startswith('stage 2/2: "a cup on the plate"') for e in events)
    # one bar over the scene: the first alignment's events in its half, the second's in the other
    halves = [(e["progress"]["stage"]["index"], e["progress"]["fraction"]) for e in events
              if e["progress"]["kind"] in ("phase_start", "step", "phase_end")]
    assert all(f <= 0.5 if index == 1 else f >= 0.5 for index, f in halves), halves
    # labelled by its steps' prompts (no description sent), an assembly
    assert (final["kind"], final["description"], final["prompt"]) == (
        "assemble", "a plate on the table; a cup on the plate", None)

    glb = api.client.get(f"/jobs/{job_id}/result.glb", headers=ALPHA).content
    check_contacts(glb)
    report = api.client.get(f"/jobs/{job_id}/report.json", headers=ALPHA).json()
    assert [(s["name"], s["on"], s["prompt"]) for s in report["stages"]] == [
        ("plate", "table", "a plate on the table"), ("cup", "plate", "a cup on the plate")]
    preview = Image.open(io.BytesIO(api.client.get(f"/jobs/{job_id}/preview.png", headers=ALPHA).content))
    assert preview.format == "PNG"


def test_chained_align_adds_to_a_finished_scene(api, assembled, files):
    job_id, early, _ = assembled
    assert (early.status_code, early.json()["error"]["code"]) == (409, "job_not_ready")  # it was still running
    spoon = trimesh.creation.cylinder(radius=0.006, height=0.12, sections=8).export(file_type="glb")
    data = {"target_job": job_id, "prompt": "a spoon in the cup", "options": json.dumps(GEOMETRY_ONLY)}
    other = api.client.post("/align", data=data, files={"source": ("spoon.glb", spoon)}, headers=BETA)
    assert (other.status_code, other.json()["error"]["code"]) == (404, "job_not_found")  # another key's job
    unknown = api.client.post("/align", data={**data, "target_job": "0" * 32}, files={"source": ("spoon.glb", spoon)},
                              headers=ALPHA)
    assert unknown.status_code == 404
    bad_on = api.client.post("/align", data={**data, "on": "saucer"}, files={"source": ("spoon.glb", spoon)},
                             headers=ALPHA)
    assert (bad_on.status_code, bad_on.json()["error"]["code"]) == (422, "invalid_name")
    both = api.client.post("/align", data=data, files={"source": ("spoon.glb", spoon), "target": ("t.glb", spoon)},
                           headers=ALPHA)
    assert (both.status_code, both.json()["error"]["code"]) == (400, "invalid_field")
    lone_on = api.client.post("/align", data={"prompt": "x", "on": "cup"}, headers=ALPHA,
                              files={"source": ("spoon.glb", spoon), "target": ("t.glb", spoon)})
    assert (lone_on.status_code, lone_on.json()["error"]["field"]) == (400, "on")

    accepted = api.client.post("/align", data=data, files={"source": ("spoon.glb", spoon)}, headers=ALPHA)
    assert accepted.status_code == 202, accepted.text
    job = finished(api, accepted.json()["id"])
    assert job["status"] == "succeeded", job
    before = dict(objects(load_objects(api.client.get(f"/jobs/{job_id}/result.glb", headers=ALPHA).content,
                                       filename="before.glb")))
    after = dict(objects(load_objects(api.client.get(f"/jobs/{job['id']}/result.glb", headers=ALPHA).content,
                                      filename="after.glb")))
    assert list(after) == ["table", "plate", "cup", "spoon"]  # separate objects, not one flattened mesh
    for name, mesh in before.items():  # placed objects never move
        np.testing.assert_allclose(after[name].vertices, mesh.vertices, atol=1e-5)
    report = api.client.get(f"/jobs/{job['id']}/report.json", headers=ALPHA).json()
    assert report["extra"]["on"] == "cup" and "cup" in report["hparams"]["reason"]


@pytest.mark.parametrize("plan, sources, status, code", [
    ("not json", ("plate",), 400, "invalid_plan"),
    ([], ("plate",), 400, "invalid_plan"),
    ([{"file": "saucer.glb", "prompt": "x"}], ("plate",), 400, "invalid_plan"),
    ([{"file": "plate.glb", "prompt": "x"}], ("plate", "cup"), 400, "invalid_plan"),  # cup.glb is never used
    ([{"file": "plate.glb", "prompt": "x", "on": "saucer"}], ("plate",), 422, "invalid_step"),
    ([{"file": "plate.glb", "prompt": "x", "on": ["table", "saucer"]}], ("plate",), 422, "invalid_step"),
    ([{"file": "plate.glb", "prompt": "x", "on": ["table", "table"]}], ("plate",), 400, "invalid_plan"),
    ([{"file": "plate.glb", "prompt": "x", "on": ["table", "a", "b"]}], ("plate",), 400, "invalid_plan"),
    ([{"file": "plate.glb", "prompt": "x", "on": []}], ("plate",), 400, "invalid_plan"),
    ([{"file": "plate.glb", "prompt": "x", "name": "table"}], ("plate",), 422, "invalid_step"),
    ([{"file": "plate.glb", "prompt": "x", "options": {"model": "random:tiny"}}], ("plate",), 400, "invalid_plan"),
    ([{"file": "plate.glb", "prompt": "x", "options": [1]}], ("plate",), 400, "invalid_plan"),
    ([{"file": "plate.glb", "prompt": "x", "image": "x.png"}], ("plate",), 400, "invalid_plan"),
    ([{"file": "plate.glb", "prompt": 5}], ("plate",), 400, "invalid_plan"),
    ([{"file": "plate.glb", "prompt": "x", "options": {"steps": 0}}], ("plate",), 422, "invalid_option"),
    ([{"file": "plate.glb"}], ("plate",), 422, "invalid_step"),  # neither prompt nor image, guidance on
    ([{"file": "plate.glb", "prompt": "a plate\x1b[2J on the table"}], ("plate",), 422, "invalid_prompt"),
    ([{"file": "plate.glb", "prompt": "x", "name": "pl\x00ate"}], ("plate",), 422, "invalid_name"),  # as POST /align
    ([{"file": "cup.glb", "prompt": "x"}] * 4, ("cup",), 413, "too_many_stages"),
    ([{"file": "plate.glb", "prompt": "x", "name": f"p{i}"} for i in range(3)], ("plate",), 413, "scene_too_large"),
])
def test_bad_plans_are_refused_before_queueing(api, files, plan, sources, status, code):
    raw = plan if isinstance(plan, str) else json.dumps(plan)
    parts = [("base", ("table.glb", files["table"]))] + [("source", (f"{n}.glb", files[n])) for n in sources]
    options = {"preset": "test"} if code == "invalid_step" and plan == [{"file": "plate.glb"}] else GEOMETRY_ONLY
    answer = api.client.post("/assemble", files=parts, data={"plan": raw, "options": json.dumps(options)},
                             headers=ALPHA)
    assert (answer.status_code, answer.json()["error"]["code"]) == (status, code), answer.text


def test_a_plain_align_over_the_scene_limit_is_refused(api, files):
    """CTP_MAX_SCENE_FACES (300 here) bounds the meshes of any job together, a plain /align's two included: a
    plate (128 faces) and a ball (320) are each under the per-mesh limit, not together."""
    ball = trimesh.creation.icosphere(subdivisions=2).export(file_type="glb")
    answer = api.client.post("/align", data={"prompt": "a ball on the plate", "options": json.dumps(GEOMETRY_ONLY)},
                             files={"target": ("plate.glb", files["plate"]), "source": ("ball.glb", ball)},
                             headers=ALPHA)
    assert answer.status_code == 413, answer.text
    assert answer.json()["error"]["code"] == "scene_too_large" and "448 faces together" in answer.json()["error"][
        "message"]


def test_a_step_s_shape_is_refused_as_the_engine_words_it(api, files):
    """The rule is the engine's (``ctp_core.assembly.plan.plan_step``, as ``ctp assemble --plan``); the API names
    the step ``plan.<i>`` and says where preset and model go."""
    answer = post_assembly(api, files, [PLAN[0], {**PLAN[1], "options": {"preset": "paper"}}])
    assert answer.status_code == 400, answer.text
    assert answer.json()["error"] == {"code": "invalid_plan", "field": "plan.1.options", "message": (
        "plan.1.options: preset and model are set for the whole assembly (the options field)")}
    unknown = post_assembly(api, files, [{**PLAN[0], "colour": "red"}], sources=("plate",)).json()["error"]
    assert (unknown["field"], unknown["message"]) == (
        "plan.0.colour", "plan.0: unknown key 'colour'; known: also, file, image, name, on, options, prompt")


def test_a_bad_stage_is_refused_before_queueing_and_named(api, files):
    """A step's option the engine cannot take (an unknown prior provider) is refused up front, naming the step;
    a stage that fails while running is named by the worker (below)."""
    plan = [PLAN[0], {**PLAN[1], "options": {"hparams_provider": "no-such-provider"}}]
    answer = post_assembly(api, files, plan)
    assert answer.status_code == 422, answer.text
    assert answer.json()["error"]["field"] == "plan.1.options.hparams_provider"
    assert answer.json()["error"]["message"].startswith("plan.1: ")


def test_a_failing_stage_is_named(files):
    """The worker's side: a stage that fails on the worker names itself. The form vets every option it can
    (an unknown prior provider is 422 at submit), so the record is built here as if that check had missed one."""
    from ctp_core.errors import CtpError
    from ctp_core.io import MeshLimits
    from ctp_core.io.loader import MeshLoader
    from service.jobs import AssemblyStep, JobRecord, new_id, now
    from service.schemas import build_config
    from worker.tasks import JobContext, assemble_job

    config = build_config(GEOMETRY_ONLY, default_model="random:tiny", allowed_models=["random:tiny"]).merged(
        {"device": "cpu", "threads": 1, "runtime": "torch"})  # as a worker runs it (worker.tasks.served)
    steps = [AssemblyStep(name="plate", file="plate.glb", prompt=PLAN[0]["prompt"], config=config),
             AssemblyStep(name="cup", file="cup.glb", prompt=PLAN[1]["prompt"], on="plate",
                          config=config.model_copy(update={"hparams_provider": "no-such-provider"}))]
    record = JobRecord(id=new_id(), owner="public", created_at=now(), kind="assemble", target_name="table",
                       target_file="table.glb", source_name="cup", source_file="cup.glb", steps=steps, config=config)
    inputs = {"target": files["table"], "source-0": files["plate"], "source-1": files["cup"]}
    with MeshLoader(1) as loader, pytest.raises(CtpError) as err:
        assemble_job(record, inputs, JobContext(loader=loader, limits=MeshLimits(),
                                                on_progress=lambda _p, _force: None, should_cancel=lambda: False))
    assert err.value.message.startswith("stage 2/2 (cup): "), err.value.message
    assert err.value.field == "steps.1.hparams_provider"


def test_the_time_limit_scales_with_the_stages(private_redis):
    import redis

    from ctp_core.config import AlignConfig
    from service.jobs import AssemblyStep, JobRecord, Jobs, new_id, now
    from service.storage import RedisStorage

    client = redis.Redis.from_url(private_redis.url)
    jobs = Jobs(client, RedisStorage(client, "asm-unit", 60), prefix="asm-unit", ttl_s=60, job_timeout_s=100,
                lease_s=5)
    try:
        steps = [AssemblyStep(name=f"s{i}", file="s.glb", prompt="p", config=AlignConfig()) for i in range(3)]
        record = jobs.submit(JobRecord(id=new_id(), owner="me", created_at=now(), kind="assemble", steps=steps,
                                       config=AlignConfig()),
                             {"target": b"b", **{f"source-{i}": b"s" for i in range(3)}}, 5)
        assert jobs.rq_queue().fetch_job(record.id).timeout == 300
        assert record.inputs()[:3] == ["target", "source-0", "image-0"]
        jobs.cancel(record.id)
        assert jobs.storage.get(record.id, "source-2") is None  # an assembly's inputs are dropped too
    finally:
        client.close()


def test_python_client_assembles_and_chains(api, worker, files, tmp_path):
    from service.client import Client, ServiceError

    picture = io.BytesIO()
    Image.new("RGB", (64, 48), (200, 30, 30)).save(picture, format="PNG")
    (tmp_path / "plate.glb").write_bytes(files["plate"])
    fast = {"preset": "test"}
    with Client(api.url, api_key="alpha") as client:
        job = client.assemble(("table.glb", files["table"]), [
            {"file": tmp_path / "plate.glb", "prompt": "a plate on the table"},
            {"file": ("cup.glb", files["cup"]), "image": ("ref.png", picture.getvalue()), "on": "plate"}],
            options=fast, base_name="table")
        final = client.wait(job["id"], timeout_s=180)
        assert final["status"] == "succeeded", final
        report = json.loads(client.download(job["id"], "report.json"))
        assert [(s["name"], s["image_guided"]) for s in report["stages"]] == [("plate", False), ("cup", True)]
        spoon = trimesh.creation.cylinder(radius=0.006, height=0.12, sections=8).export(file_type="glb")
        chained = client.submit(None, ("spoon.glb", spoon), "a spoon in the cup", options=fast,
                                target_job=job["id"], source_name="spoon")
        assert client.wait(chained["id"], timeout_s=180)["status"] == "succeeded"
        scene = load_objects(client.download(chained["id"]), filename="scene.glb")
        assert list(scene.geometry) == ["table", "plate", "cup", "spoon"]
        with pytest.raises(ServiceError) as err:
            client.assemble(("table.glb", files["table"]), [{"file": ("cup.glb", files["cup"]), "image": None}],
                            options=fast)
        assert (err.value.status, err.value.code) == (422, "invalid_step")  # neither prompt nor image


ROOM = [{"file": "armchair.glb", "prompt": "an armchair far from the sofa"},
        {"file": "lamp.glb", "prompt": LAMP_PROMPT, "on": ["sofa", "armchair"]}]


@pytest.fixture(scope="module")
def room():
    return {name: mesh.export(file_type="glb") for name, mesh in sofa_armchair_lamp().items()}


def post_room(api, room, plan, sources):
    parts = [("base", ("sofa.glb", room["sofa"]))] + [("source", (f"{n}.glb", room[n])) for n in sources]
    return api.client.post("/assemble", files=parts, headers=ALPHA,
                           data={"plan": json.dumps(plan), "options": json.dumps(GEOMETRY_ONLY)})


def test_an_assembly_step_between_two_placed_objects(api, worker, room):
    """A step's ``on`` as a list of two: checked against the objects placed before it, then run and reported."""
    unplaced = post_room(api, room, [ROOM[0], {**ROOM[1], "on": ["sofa", "table"]}], ("armchair", "lamp"))
    assert (unplaced.status_code, unplaced.json()["error"]["code"], unplaced.json()["error"]["field"]) == (
        422, "invalid_step", "plan.1.on"), unplaced.text
    assert "'table' is not an object placed before it" in unplaced.json()["error"]["message"]
    accepted = post_room(api, room, ROOM, ("armchair", "lamp"))
    assert accepted.status_code == 202, accepted.text
    job = finished(api, accepted.json()["id"])
    assert job["status"] == "succeeded", job
    report = api.client.get(f"/jobs/{job['id']}/report.json", headers=ALPHA).json()
    assert [(s["name"], s["on"], s["grounds"]) for s in report["stages"]] == [
        ("armchair", "sofa", ["sofa"]), ("lamp", "sofa", ["sofa", "armchair"])]
    assert report["stages"][1]["relation"]["name"] == "between" and report["stages"][1]["relation"]["holds"]
    check_between(api.client.get(f"/jobs/{job['id']}/result.glb", headers=ALPHA).content)


def test_a_chained_job_between_two_objects_of_the_scene(api, worker, room):
    """``on`` given twice (one part per name) on a ``target_job``: the two objects of that scene it relates to."""
    from service.client import Client

    accepted = post_room(api, room, ROOM[:1], ("armchair",))
    assert accepted.status_code == 202, accepted.text
    scene = finished(api, accepted.json()["id"])
    assert scene["status"] == "succeeded", scene
    data = {"target_job": scene["id"], "prompt": LAMP_PROMPT, "options": json.dumps(GEOMETRY_ONLY)}
    lamp = {"source": ("lamp.glb", room["lamp"])}
    for on, status, code in [(["sofa", "armchair", "sofa"], 400, "invalid_field"),
                             (["sofa", "sofa"], 400, "invalid_field"),
                             (["sofa", "table"], 422, "invalid_name")]:
        answer = api.client.post("/align", data={**data, "on": on}, files=lamp, headers=ALPHA)
        assert (answer.status_code, answer.json()["error"]["code"], answer.json()["error"]["field"]) == (
            status, code, "on"), (on, answer.text)
    with Client(api.url, api_key="alpha") as client:
        job = client.submit(None, ("lamp.glb", room["lamp"]), LAMP_PROMPT, options=GEOMETRY_ONLY,
                            target_job=scene["id"], on=["armchair", "sofa"])
        assert client.wait(job["id"], timeout_s=180)["status"] == "succeeded"
        report = json.loads(client.download(job["id"], "report.json"))
        glb = client.download(job["id"])
    assert (report["extra"]["on"], report["extra"]["grounds"]) == ("armchair", ["armchair", "sofa"])
    assert report["relation"]["name"] == "between" and report["relation"]["holds"], report["relation"]
    check_between(glb)


def test_control_characters_in_a_source_file_name(api, files):
    """As POST /align's: a raw multipart body carries the byte as sent (httpx would quote it)."""
    boundary = "ctpboundary"
    parts = [("base", "table.glb", files["table"]), ("source", "pl\x01ate.glb", files["plate"])]
    body = b"".join(f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; filename="{filename}"\r\n'
                    f"Content-Type: application/octet-stream\r\n\r\n".encode() + data + b"\r\n"
                    for name, filename, data in parts)
    plan = json.dumps([{"file": "pl\x01ate.glb", "prompt": "a plate on the table"}])
    body += f'--{boundary}\r\nContent-Disposition: form-data; name="plan"\r\n\r\n{plan}\r\n'.encode()
    body += f"--{boundary}--\r\n".encode()
    answer = api.client.post("/assemble", content=body,
                             headers={**ALPHA, "Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert (answer.status_code, answer.json()["error"]["code"], answer.json()["error"]["field"]) == (
        422, "invalid_name", "source"), answer.text


def test_the_api_process_imports_no_torch():
    """The API checks plans and options with torch-free modules (``plan``, ``config``, ``options``); only the
    workers load the engine. A fresh interpreter, so what the other tests imported does not count."""
    probe = subprocess.run([sys.executable, "-c", "import service.app, sys; print('torch' in sys.modules)"],
                           cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, text=True,
                           timeout=120)
    assert probe.returncode == 0, probe.stderr
    assert probe.stdout.strip() == "False"
