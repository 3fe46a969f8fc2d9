"""What a caller without a key learns about the machine: no filesystem path (absolute, ``~``-relative, a cache folder's
name), no hostname, no version, in ``/readyz`` and in any error answer (``service.redact``); and no path in any other
answer such a caller can get (the page, its files, the docs, the schema).

The workers' reasons here name real paths: the session's Hugging Face cache (where the default model's weights are
looked for) and a model folder that does not exist; every answer is searched for them and for path shapes."""

from __future__ import annotations

import json
import os
import platform
import re
import socket

import fastapi
import httpx
import pytest
import redis
import trimesh
import uvicorn

from ctp_core.config import DEFAULT_MODEL
from ctp_core.guide.checkpoints import missing
from service.redact import PLACEHOLDER, redact
from service.storage import RedisStorage
from tests.conftest import REPO, Api, park_worker, service_env, wait_for
from tests.test_service import BALL, BOX

KEY = "stranger-test-key"
JOB = "0" * 32


def leaks(answer: httpx.Response, *, machine: bool) -> list[str]:
    """What ``answer`` gives away: paths always; with ``machine`` (/readyz, errors) also the hostname and versions."""
    text = answer.text + "".join(f"{k}: {v}\n" for k, v in answer.headers.items())
    found = [p for p in {str(REPO), os.environ["HF_HOME"], str(os.path.expanduser("~"))} if len(p) > 1 and p in text]
    found += re.findall(r"(?:^|[\s\"'(=:])((?:/tmp|/root|/home|/var|/usr|/opt|/srv|~)/[^\s\"')]*)", text)
    found += [s for s in (".cache/", "models--", "huggingface/hub") if s in text]
    if machine:
        found += re.findall(rf"\b{re.escape(socket.gethostname())}\b", text)
        found += [v for v in (platform.python_version(), fastapi.__version__, uvicorn.__version__) if v in text]
        found += [f"server: {answer.headers['server']}"] if re.search(r"\d", answer.headers.get("server", "")) else []
    return found


def strangers_requests(client: httpx.Client) -> list[tuple[str, httpx.Response]]:
    """Every kind of answer a caller without a key can get from the API."""
    files = {"target": ("box.glb", BOX), "source": ("ball.glb", BALL)}
    sent = {
        "readyz": client.get("/readyz"),
        "healthz": client.get("/healthz"),
        "jobs": client.get("/jobs"),
        "job": client.get(f"/jobs/{JOB}"),
        "result": client.get(f"/jobs/{JOB}/result.glb"),
        "cancel": client.delete(f"/jobs/{JOB}"),
        "align": client.post("/align", files=files, data={"prompt": "a ball on a box"}),
        "guided align": client.post("/align", files=files, data={
            "prompt": "a ball on a box", "options": json.dumps({"preset": "test", "lambda_clip": 1})}),
        "unreadable mesh": client.post("/align", files={"target": ("box.glb", b"not a mesh"), "source": (
            "ball.glb", BALL)}, data={"prompt": "a ball on a box"}),
        "no such route": client.get("/nowhere"),
        "wrong method": client.put("/readyz"),
        "bad query": client.get("/jobs", params={"limit": "x"}),
    }
    return list(sent.items())


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "strangers", model="auto", api_keys=KEY)


def test_redact_keeps_what_helps_and_drops_paths():
    said = redact("weights for 'openai/clip' are not in the Hugging Face cache (/srv/x/.cache/huggingface/hub); "
                  "pass hf:/path/to/dir, see ~/.cache/ctp or ./models/clip; use POST /align; step 2/3")
    assert said == (f"weights for 'openai/clip' are not in the Hugging Face cache ({PLACEHOLDER}); pass "
                    f"hf:{PLACEHOLDER}, see {PLACEHOLDER} or {PLACEHOLDER}; use POST /align; step 2/3")


def test_a_caller_without_a_key_learns_no_path_host_or_version(api, env):
    """Keys on, model auto, a worker without the default model's weights (its reason names the session's cache)."""
    reason = missing(DEFAULT_MODEL)
    assert reason is not None and os.environ["HF_HOME"] in reason  # what a worker publishes names a real path
    leave = park_worker(env, {"auto": None, DEFAULT_MODEL: reason})
    try:
        answers = strangers_requests(api.client)
        ready = dict(answers)["readyz"].json()
        assert (ready["guide"], ready["get_model"]) == ("none", "ctp models pull openai/clip-vit-base-patch32")
        assert f"not in the Hugging Face cache ({PLACEHOLDER})" in ready["why"]
        assert {name: a.status_code for name, a in answers if name not in ("readyz", "healthz")} == {
            "jobs": 401, "job": 401, "result": 401, "cancel": 401, "align": 401, "guided align": 401,
            "unreadable mesh": 401, "no such route": 404, "wrong method": 405, "bad query": 401}
        with_key = api.client.post("/align", headers={"Authorization": f"Bearer {KEY}"}, files={
            "target": ("box.glb", BOX), "source": ("ball.glb", BALL)}, data={
            "prompt": "a ball on a box", "options": json.dumps({"preset": "test", "lambda_clip": 1})})
        assert (with_key.status_code, with_key.json()["error"]["code"]) == (503, "model_unavailable")
        assert "not in the Hugging Face cache" in with_key.json()["error"]["message"]  # which model, and why
        answers.append(("guided align with a key", with_key))
        for page in ("/", "/docs", "/redoc", "/openapi.json", "/static/page.js"):
            answer = api.client.get(page)
            assert answer.status_code == 200 and not leaks(answer, machine=False), (page, leaks(answer, machine=False))
        told = {name: found for name, answer in answers if (found := leaks(answer, machine=True))}
        assert not told, told
    finally:
        leave()


def test_without_keys_no_error_answer_names_a_path(private_redis, tmp_path):
    """Keys off (every caller is a stranger), a named model whose folder does not exist: /readyz and the submits
    are 503 ``model_unavailable`` saying why, without the folder."""
    folder = tmp_path / "weights"
    env = service_env(private_redis.url, "strangers-open", model=f"hf:{folder}")
    api = Api(env)
    leave = park_worker(env, {f"hf:{folder}": missing(f"hf:{folder}")})
    try:
        answers = strangers_requests(api.client)
        statuses = {name: a.status_code for name, a in answers}
        assert statuses["readyz"] == statuses["align"] == 503 and statuses["unreadable mesh"] == 422, statuses
        message = dict(answers)["readyz"].json()["error"]["message"]
        assert message == (f"no live worker can run the default model (CTP_MODEL) 'hf:{PLACEHOLDER}': no transformers "
                           f"model directory at {PLACEHOLDER} (expected config.json from save_pretrained)")
        told = {name: found for name, answer in answers if (found := leaks(answer, machine=True) + (
            [str(folder)] if str(folder) in answer.text else []))}
        assert not told, told
    finally:
        leave()
        api.stop()



def test_no_job_answer_or_report_names_a_path(api, env, worker):
    """A real worker under model auto without the default model's weights: the guide_why it writes names the
    session's Hugging Face cache. Every answer about an alignment and an assembly (submit, the job, the list, the
    events, report.json with each stage's guide_why, and report.json as stored) says ``<path>`` instead, and names no
    other path."""
    auth = {"Authorization": f"Bearer {KEY}"}
    cube = trimesh.creation.box((0.1, 0.1, 0.1)).export(file_type="glb")
    submits = [
        api.client.post("/align", headers=auth, files={"target": ("box.glb", BOX), "source": ("ball.glb", BALL)},
                        data={"prompt": "a ball on a box", "options": json.dumps({"preset": "test"})}),
        api.client.post("/assemble", headers=auth, files=[
            ("base", ("box.glb", BOX)), ("source", ("ball.glb", BALL)), ("source", ("cube.glb", cube))], data={
            "plan": json.dumps([{"file": "ball.glb", "prompt": "a ball on the box"},
                                {"file": "cube.glb", "prompt": "a cube on the box", "on": "box"}]),
            "options": json.dumps({"preset": "test"})}),
    ]
    assert [s.status_code for s in submits] == [202, 202], [s.text for s in submits]
    answers = list(submits)
    storage = RedisStorage(redis.Redis.from_url(env["REDIS_URL"]), env["CTP_KEY_PREFIX"], 600)
    for job_id in (s.json()["id"] for s in submits):
        wait_for(lambda job_id=job_id: api.client.get(f"/jobs/{job_id}", headers=auth).json()["status"] in (
            "succeeded", "failed"), 300, f"job {job_id} to end")
        job = api.client.get(f"/jobs/{job_id}", headers=auth)
        report = api.client.get(f"/jobs/{job_id}/report.json", headers=auth)
        assert (job.json()["status"], report.status_code) == ("succeeded", 200), job.text
        assert f"not in the Hugging Face cache ({PLACEHOLDER})" in job.json()["guide_why"]  # a path was there
        whys = [report.json().get("guide_why")] + [s["guide_why"] for s in report.json().get("stages", [])]
        assert all(f"({PLACEHOLDER})" in why for why in whys if why is not None) and any(whys), whys
        stored = storage.get(job_id, "report.json").decode()  # as the worker wrote it: redacted at rest too
        assert f"({PLACEHOLDER})" in stored and os.environ["HF_HOME"] not in stored
        answers += [job, report, api.client.get(f"/jobs/{job_id}/events", headers=auth),
                    api.client.delete(f"/jobs/{job_id}", headers=auth)]
    answers.append(api.client.get("/jobs", headers=auth))
    told = {answer.request.url.path: found for answer in answers if (found := leaks(answer, machine=False))}
    assert not told, told
