"""Model ``auto`` (the default CTP_MODEL) over HTTP, with real workers: where the default model's weights are
missing, ``/readyz`` is 200 and says no guide, why and the command that gets the model; a job with default
options succeeds without a guide and says so (record and report), while a job that asks for guidance itself (a
reference image, ``lambda_clip``) is refused up front. Where the weights are in the workers' cache (a small random
CLIP saved as the default model in the real layout), auto picks it, and the job says so."""

from __future__ import annotations

import io
import json

import pytest

from ctp_core.config import DEFAULT_MODEL
from tests.conftest import Api, Worker, service_env, wait_for, wait_ready
from tests.test_guidance import _save_tiny_hf_clip
from tests.test_service import BALL, BOX, submit

DEFAULTS = {"preset": "test"}  # what a client sends that sets no model and no guidance


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "auto-none", model="auto")


def finished(api: Api, job_id: str) -> dict:
    return wait_for(lambda: (j := api.client.get(f"/jobs/{job_id}").json())["status"] in ("succeeded", "failed")
                    and j, 120, f"job {job_id} to end")


def test_without_weights_readyz_is_200_and_says_no_guide(api, worker):
    answer = api.client.get("/readyz")
    assert answer.status_code == 200, answer.text
    ready = answer.json()
    assert (ready["status"], ready["guide"]) == ("ready", "none")
    assert "not in the Hugging Face cache" in ready["why"]
    assert ready["get_model"] == "ctp models pull openai/clip-vit-base-patch32"


def test_a_job_with_default_options_succeeds_without_a_guide_and_says_so(api, worker):
    accepted = submit(api, options=DEFAULTS)
    assert accepted.status_code == 202, accepted.text
    job = finished(api, accepted.json()["id"])
    assert job["status"] == "succeeded", job
    assert job["guide"] == "none" and "the geometry and the prompt's relation place the source" in job["guide_why"]
    report = api.client.get(f"/jobs/{job['id']}/report.json").json()
    assert (report["guide"], report["guide_why"], report["model"]) == ("none", job["guide_why"], None)
    assert report["config"]["loss"]["lambda_clip"] == 0.0


def test_a_job_asking_for_guidance_is_refused_up_front(api, worker):
    from PIL import Image

    png = io.BytesIO()
    Image.new("RGB", (16, 16), "red").save(png, "PNG")
    image = api.client.post("/align", files={"target": ("box.glb", BOX), "source": ("ball.glb", BALL),
                                             "image": ("ref.png", png.getvalue())},
                            data={"options": json.dumps(DEFAULTS)})
    text = submit(api, options={**DEFAULTS, "lambda_clip": 1})
    for refused in (image, text):
        assert refused.status_code == 503, refused.text
        error = refused.json()["error"]
        assert (error["code"], error["field"]) == ("model_unavailable", "options.model")
        assert error["message"].startswith("this job asks for guidance itself (a reference image, lambda_clip or ")
        assert DEFAULT_MODEL in error["message"] and "ctp models pull" in error["message"]


def test_with_the_default_model_cached_auto_picks_it(private_redis, tmp_path_factory):
    home = tmp_path_factory.mktemp("hf-home-with-clip")
    commit = "c" * 40
    repo = home / "hub" / f"models--{DEFAULT_MODEL.removeprefix('hf:').replace('/', '--')}"
    (repo / "snapshots" / commit).mkdir(parents=True)
    _save_tiny_hf_clip(repo / "snapshots" / commit)
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(commit)
    env = {**service_env(private_redis.url, "auto-cached", model="auto"), "HF_HOME": str(home)}
    api = Api(env)
    worker = Worker(env, home / "worker.log")
    try:
        wait_ready(api)
        ready = api.client.get("/readyz").json()
        assert (ready["guide"], ready["get_model"]) == (DEFAULT_MODEL, None)
        accepted = submit(api, options=DEFAULTS)
        assert accepted.status_code == 202, accepted.text
        job = finished(api, accepted.json()["id"])
        assert job["status"] == "succeeded", job
        assert job["guide"] == DEFAULT_MODEL and job["guide_why"].startswith("auto: ")
        assert api.client.get(f"/jobs/{job['id']}/report.json").json()["model"] == DEFAULT_MODEL
    finally:
        worker.stop()
        api.stop()
