"""Hostile input against a real server (uvicorn on a socket, real Redis): a pathological upload costs
the API seconds, never its threads; no form field or options JSON that a client can send gives a 500."""

from __future__ import annotations

import json
import time
from concurrent.futures import ThreadPoolExecutor

import pytest
import trimesh
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from ctp_core.config import AlignConfig
from ctp_core.config.options import OPTION_PATHS
from tests.conftest import Api, park_worker, service_env, wait_for
from tests.test_loader import wide_glb
from tests.test_service import BALL, BOX, FAST, deep_chain_glb, glb


@pytest.fixture(scope="module")
def env(private_redis):
    # a raised node budget lets a slow-to-flatten file through the JSON checks, to meet the wall-time limit
    return service_env(private_redis.url, "hostile", max_active_jobs=100_000, load_timeout_s=2, max_nodes=10**6)


@pytest.fixture(scope="module")
def parked(env):
    """A live worker as the API sees it, consuming nothing: submissions are accepted (no ``no_worker``)."""
    leave = park_worker(env)
    yield
    leave()


def _post(api: Api, target=("box.glb", BOX), source=("ball.glb", BALL), data=None):
    return api.client.post("/align", files={"target": target, "source": source},
                           data={"prompt": "a ball on a box", "options": json.dumps(FAST)} if data is None else data)


def test_pathological_glbs_are_refused_quickly_and_the_api_stays_up(api, parked):
    """The reported DoS: a 100 kB chain of 2000 nodes held an API thread for minutes; three at once took
    the API to 4.7 GB. Now the JSON budget refuses it at once, and a file inside the budgets that is
    still slow to load is cut off at the wall-time limit (2 s here) in a loading process."""
    assert _post(api).status_code == 202  # warm: the loading processes are started
    chain = ("deep.glb", deep_chain_glb(2000))
    slow = ("wide.glb", wide_glb(60_000))
    started = time.monotonic()
    with ThreadPoolExecutor(4) as pool:
        chains = [pool.submit(_post, api, target=chain) for _ in range(3)]
        slowed = pool.submit(_post, api, source=slow)
        while not slowed.done():  # meanwhile the API answers
            assert api.client.get("/healthz", timeout=2).status_code == 200
            time.sleep(0.2)
    for answer in [f.result() for f in chains]:
        assert (answer.status_code, answer.json()["error"]["code"]) == (413, "mesh_too_complex")
    answer = slowed.result()
    assert (answer.status_code, answer.json()["error"]["code"]) == (413, "mesh_too_complex"), answer.text
    assert "took over 2 s" in answer.json()["error"]["message"]
    assert time.monotonic() - started < 15
    assert _post(api).status_code == 202  # the killed loading process was replaced


_json = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
                     lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                                 max_size=4), max_leaves=12)
_options = (st.dictionaries(st.sampled_from(sorted(OPTION_PATHS)) | st.text(max_size=12), _json, max_size=5)
            .map(json.dumps)
            | st.fixed_dictionaries({}, optional={"preset": st.sampled_from(["test", "default", "turbo"]),
                                                  "seed": st.integers() | st.integers(0, 2**32),
                                                  "steps": st.integers() | st.integers(2, 50),
                                                  "restarts": st.integers() | st.integers(1, 8),
                                                  "contact_ratio": st.floats(),
                                                  "size_ratio": st.floats(), "model": st.just("random:tiny"),
                                                  "scale": st.booleans()}).map(json.dumps)
            | st.text(max_size=200)
            | st.integers(1, 3000).map(lambda n: "[" * n + "]" * n))
_field = st.none() | st.text(max_size=600)
_prompt = st.just("a ball on top of a box") | _field  # a third valid, so options are judged too


@settings(max_examples=300, deadline=None, derandomize=True, database=None,  # the same 300 cases in every CI run
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(options=_options, prompt=_prompt, target_name=_field, source_name=_field,
       source_file=st.sampled_from(["ball.glb", "ball", "ball.GLB", "b.zip", ".glb"]))
def test_no_form_or_options_gives_a_500(api, parked, options, prompt, target_name, source_name, source_file):
    data = {k: v for k, v in {"options": options, "prompt": prompt, "target_name": target_name,
                              "source_name": source_name}.items() if v is not None}
    answer = _post(api, source=(source_file, BALL), data=data)
    event(f"HTTP {answer.status_code}")  # --hypothesis-show-statistics: how many were accepted, and why refused
    assert answer.status_code < 500, answer.text
    body = answer.json()
    if answer.status_code == 202:  # accepted: what was queued is a config the engine takes
        job = api.client.get(f"/jobs/{body['id']}").json()
        assert api.client.delete(f"/jobs/{body['id']}").status_code == 200
        assert job["status"] == "queued"
    else:
        assert set(body["error"]) == {"code", "message", "field"} and body["error"]["code"]


def test_accepted_options_build_an_engine_config(api, parked):
    """What the property test cannot see from outside: an accepted seed, steps... fit AlignConfig."""
    from service.schemas import build_config

    config = build_config({"seed": 2**32 - 1, "steps": 100_000}, default_model="random:tiny",
                          allowed_models=["random:tiny"])
    assert AlignConfig.model_validate(config.model_dump()).seed == 2**32 - 1


def test_single_triangle_and_planar_uploads_succeed(api, worker):
    """Once accepted with 202 and then failed with internal_error (QhullError): a valid input succeeds."""
    triangle = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], process=False)
    square = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], [[0, 1, 2], [0, 2, 3]], process=False)
    ids = [_post(api, target=("square.glb", glb(square)), source=("triangle.glb", glb(triangle))).json()["id"],
           _post(api, source=("triangle.glb", glb(triangle))).json()["id"]]
    for job_id in ids:
        job = wait_for(lambda job_id=job_id: (j := api.client.get(f"/jobs/{job_id}").json())["status"]
                       in ("succeeded", "failed") and j, 180, "the job to end")
        assert job["status"] == "succeeded", job["error"]
        assert api.client.get(f"/jobs/{job_id}/result.glb").status_code == 200


def test_control_characters_in_a_file_name(api, parked):
    """httpx quotes file names; a raw multipart body carries the byte as sent."""
    boundary = "ctpboundary"
    parts = [("target", "bo\x01x.glb", BOX), ("source", "ball.glb", BALL)]
    body = b"".join(f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; filename="{filename}"\r\n'
                    f"Content-Type: application/octet-stream\r\n\r\n".encode() + data + b"\r\n"
                    for name, filename, data in parts)
    body += f'--{boundary}\r\nContent-Disposition: form-data; name="prompt"\r\n\r\na ball on a box\r\n'.encode()
    body += f"--{boundary}--\r\n".encode()
    answer = api.client.post("/align", content=body,
                             headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    assert (answer.status_code, answer.json()["error"]) == (422, {
        "code": "invalid_name", "field": "target",
        "message": "the target file name holds control characters or is over 255 characters"})
