"""Readiness means "a job submitted now can succeed": a real worker whose default model has no weights
here (an ``hf:`` path that does not exist) makes ``/readyz`` and ``POST /align`` answer 503
``model_unavailable`` with the worker's reason (its paths redacted: any caller may read it), while jobs it
can run (another allowed model, or a geometry-only job that needs no model) are still accepted and succeed.
What only the worker knows (its device and runtime) it checks when it takes a job: a job it cannot serve
fails at once."""

from __future__ import annotations

import json

import pytest

from tests.conftest import Api, Worker, service_env, wait_for
from tests.test_service import BALL, BOX, FAST, submit

MISSING = "hf:/nonexistent/ctp-weights"
ONNX = "onnx:/nonexistent/ctp-onnx"  # forward only: ONNX Runtime on the CPU, while this worker's runtime is torch


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "no-weights", model=MISSING, models=f"random:tiny,{ONNX}")


@pytest.fixture(scope="module")
def live_worker(env, api, tmp_path_factory):
    process = Worker(env, tmp_path_factory.mktemp("logs") / "worker.log")
    wait_for(lambda: api.client.get("/readyz").json()["error"]["code"] != "no_worker", 90,
             "the worker's first heartbeat", interval_s=0.25)
    yield process
    process.stop()


def finished(api: Api, job_id: str) -> dict:
    return wait_for(lambda: (j := api.client.get(f"/jobs/{job_id}").json())["status"] in ("succeeded", "failed")
                    and j, 120, f"job {job_id} to end")


def test_readyz_says_the_default_model_is_unavailable_and_why(api, live_worker):
    answer = api.client.get("/readyz")
    assert answer.status_code == 503
    error = answer.json()["error"]
    assert error["code"] == "model_unavailable"
    assert error["message"] == ("no live worker can run the default model (CTP_MODEL) 'hf:<path>': no transformers "
                                "model directory at <path> (expected config.json from save_pretrained)")


def test_a_job_needing_the_missing_model_is_refused_up_front(api, live_worker):
    refused = submit(api, options={"preset": "test"})  # the default model
    assert refused.status_code == 503, refused.text
    assert refused.json()["error"]["code"] == "model_unavailable"
    assert refused.json()["error"]["field"] == "options.model"


def test_an_assembly_needing_the_missing_model_is_refused_up_front(api, live_worker):
    plan = json.dumps([{"file": "ball.glb", "prompt": "a ball on top of a box"}])
    refused = api.client.post("/assemble", files=[("base", ("box.glb", BOX)), ("source", ("ball.glb", BALL))],
                              data={"plan": plan, "options": json.dumps({"preset": "test"})})
    assert (refused.status_code, refused.json()["error"]["code"]) == (503, "model_unavailable"), refused.text


def test_jobs_the_worker_can_run_are_accepted_and_succeed(api, live_worker):
    with_model = submit(api, options=FAST)  # random:tiny, which the worker has
    geometry_only = submit(api, options={"preset": "test", "lambda_clip": 0})  # the default model, unused
    for accepted in (with_model, geometry_only):
        assert accepted.status_code == 202, accepted.text
        job = finished(api, accepted.json()["id"])
        assert job["status"] == "succeeded", job


def test_an_assembly_with_one_guided_step_needs_the_model(api, live_worker):
    """Steps carry their own options: the worker loads the model when any stage is guided (its own
    ``lambda_clip``), whatever the assembly's options say, so readiness looks at every stage's config."""
    parts = [("base", ("box.glb", BOX)), ("source", ("ball.glb", BALL))]
    geometry_only = json.dumps({"preset": "test", "lambda_clip": 0})
    guided = json.dumps([{"file": "ball.glb", "prompt": "a ball on a box", "options": {"lambda_clip": 1}}])
    refused = api.client.post("/assemble", files=parts, data={"plan": guided, "options": geometry_only})
    assert (refused.status_code, refused.json()["error"]["code"]) == (503, "model_unavailable"), refused.text
    assert "can run model 'hf:<path>': no transformers model directory at <path>" in refused.json()["error"]["message"]
    geometry_step = json.dumps([{"file": "ball.glb", "options": {"lambda_clip": 0}}])  # and the other way round
    accepted = api.client.post("/assemble", files=parts, data={"plan": geometry_step,
                                                               "options": json.dumps({"preset": "test"})})
    assert accepted.status_code == 202, accepted.text  # guided assembly options, but no stage needs the model
    assert finished(api, accepted.json()["id"])["status"] == "succeeded"


def test_a_job_the_worker_cannot_serve_fails_when_it_is_taken(api, live_worker, env):
    """A geometry-only job may name any allowed model, so POST /align accepts the forward-only ``onnx:`` one;
    this worker's runtime (CTP_RUNTIME=torch) cannot serve it, which the worker finds when it takes the job:
    failed with ``worker_cannot_serve`` before any mesh or model loads (the assembly's uploads here are not
    meshes at all, which a worker that loaded them would fail as ``mesh_unreadable``)."""
    import redis

    from service.jobs import AssemblyStep, JobRecord, Jobs, new_id, now
    from service.schemas import build_config
    from service.storage import RedisStorage

    accepted = submit(api, options={"preset": "test", "lambda_clip": 0, "model": ONNX})
    assert accepted.status_code == 202, accepted.text
    client = redis.Redis.from_url(env["REDIS_URL"])
    jobs = Jobs(client, RedisStorage(client, env["CTP_KEY_PREFIX"], 600), prefix=env["CTP_KEY_PREFIX"], ttl_s=600,
                job_timeout_s=60, lease_s=5)
    try:
        config = build_config({"preset": "test", "lambda_clip": 0, "model": ONNX}, default_model=MISSING,
                              allowed_models=[MISSING, ONNX])
        steps = [AssemblyStep(name="ball", file="ball.glb", config=config)]
        assembly = jobs.submit(JobRecord(id=new_id(), owner="public", created_at=now(), kind="assemble",
                                         target_file="box.glb", steps=steps, config=config),
                               {"target": b"not a mesh", "source-0": b"nor this"}, 10)
    finally:
        client.close()
    for job_id in (accepted.json()["id"], assembly.id):
        job = finished(api, job_id)
        assert job["status"] == "failed" and job["error"]["code"] == "worker_cannot_serve", job
        message = job["error"]["message"]
        assert message.startswith("this worker runs jobs with device cpu (CTP_DEVICE), ")
        # the model's path redacted as every path in a job answer is (service.redact)
        assert "runtime torch (CTP_RUNTIME) and cannot serve this one: model 'onnx:<path>' runs only in " in message
        progress = job["progress"]
        assert (progress["stage"]["name"], progress["message"]) == ("loading", "failed: worker_cannot_serve")
