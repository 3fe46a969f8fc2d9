"""Adjusting a result by hand (``POST /jobs/{id}/adjust``) against a real Redis, a real uvicorn and a real
``ctp worker`` with the tiny random model: the refusals, drop and push settled into contact by the worker,
a save that replaces the job's result (the original kept) and a chained job that builds on the adjusted scene.

Contact is measured on the GLBs themselves with trimesh, not with the engine's own samples.
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import redis
import trimesh

from ctp_core.config import AlignConfig
from service.adjustments import AdjustmentRecord, Adjustments, AdjustRequest
from service.client import Client
from service.deps import digest
from service.jobs import AssemblyStep, JobRecord, Jobs, now
from service.storage import RedisStorage
from tests.conftest import park_worker, service_env, wait_for

KEY, OTHER = "adjust-key", "other-key"
AUTH, OTHERS = {"Authorization": f"Bearer {KEY}"}, {"Authorization": f"Bearer {OTHER}"}
FAST = {"preset": "test", "model": "random:tiny", "seed": 3}
TABLE = trimesh.creation.box((1.0, 0.1, 0.8))  # top at y = 0.05, x in [-0.5, 0.5]
BALL = trimesh.creation.icosphere(subdivisions=2, radius=0.15)
DIAGONAL = float(np.linalg.norm(BALL.extents))


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "adjust", api_keys=f"{KEY},{OTHER}", max_active_jobs=10)


def submit(api, headers=AUTH, **data):
    files = {"target": ("table.glb", TABLE.export(file_type="glb")),
             "source": ("ball.glb", BALL.export(file_type="glb"))}
    answer = api.client.post("/align", headers=headers, files=files,
                             data={"prompt": "a ball on top of a table", "options": json.dumps(FAST), **data})
    assert answer.status_code in (200, 202), answer.text
    return answer.json()["id"]


def succeeded(api, job_id: str) -> dict:
    return wait_for(lambda: (j := api.client.get(f"/jobs/{job_id}", headers=AUTH).json())["status"] == "succeeded"
                    and j, 240, f"job {job_id} to succeed", interval_s=0.25)


def post(api, job_id: str, body: dict, headers=AUTH, wait: int | None = 60):
    extra = {"Prefer": f"wait={wait}"} if wait is not None else {}
    # json.dumps, not httpx's json=: a client may send NaN (Python's json writes NaN)
    return api.client.post(f"/jobs/{job_id}/adjust", content=json.dumps(body),
                           headers={**headers, **extra, "Content-Type": "application/json"})


def error(answer) -> tuple[int, str, str | None]:
    body = answer.json()["error"]
    return answer.status_code, body["code"], body["field"]


def moved(matrix, dx=0.0, dy=0.0, dz=0.0) -> list[list[float]]:
    out = np.array(matrix, dtype=float)
    out[:3, 3] += [dx, dy, dz]
    return out.tolist()


def ball_in(glb: bytes, node: str = "ball") -> tuple[np.ndarray, trimesh.Trimesh]:
    """The source node's own matrix in a result GLB (not flattened; named by ball.glb) and the ball it places, target
    file frame."""
    scene = trimesh.load(io.BytesIO(glb), file_type="glb")
    matrix, geometry = scene.graph[node]
    return np.asarray(matrix), scene.geometry[geometry].copy().apply_transform(matrix)


def sits_on_table(ball: trimesh.Trimesh) -> tuple[float, float]:
    """(gap, depth) between the placed ball and the table, measured on the meshes, in ball diagonals: both are
    convex, so the ball's vertex nearest the table (or deepest in it) gives them."""
    signed = float(trimesh.proximity.signed_distance(TABLE, ball.vertices).max())  # positive inside the table
    return max(0.0, -signed) / DIAGONAL, max(0.0, signed) / DIAGONAL


def test_adjust_is_refused_for_unknown_others_and_unfinished_jobs(api, env):
    leave = park_worker(env)  # a live worker that takes nothing: the job stays queued
    try:
        job_id = submit(api)
        body = {"transform": np.eye(4).tolist()}
        assert error(post(api, job_id, body, wait=None)) == (409, "job_not_ready", None)
        assert error(post(api, "0" * 32, body)) == (404, "job_not_found", None)
        assert error(post(api, job_id, body, headers=OTHERS)) == (404, "job_not_found", None)
        assert api.client.post(f"/jobs/{job_id}/adjust", json=body).status_code == 401
        assert api.client.delete(f"/jobs/{job_id}", headers=AUTH).status_code == 200
    finally:
        leave()


def test_an_assembly_adjusts_one_placed_object_named(api, env):
    client = redis.Redis.from_url(env["REDIS_URL"])
    prefix = env["CTP_KEY_PREFIX"]
    jobs = Jobs(client, RedisStorage(client, prefix, 600), prefix=prefix, ttl_s=600, job_timeout_s=60, lease_s=5)
    step = AssemblyStep(name="mug", file="mug.glb", prompt="a mug on the table", config=AlignConfig())
    record = JobRecord(id="a" * 32, owner=digest(KEY), status="succeeded", created_at=now(), config=AlignConfig(),
                       kind="assemble", target_name="table", steps=[step])
    client.set(jobs.record_key(record.id), record.model_dump_json(), ex=600)
    try:
        eye = np.eye(4).tolist()
        for body in ({"transform": eye}, {"transform": eye, "object": "table"}, {"transform": eye, "object": "cup"}):
            assert error(post(api, record.id, body)) == (422, "invalid_object", "object"), body
    finally:
        client.delete(jobs.record_key(record.id))
        client.close()


def test_an_adjustment_whose_worker_is_gone_fails_worker_lost(env):
    client = redis.Redis.from_url(env["REDIS_URL"])
    prefix = env["CTP_KEY_PREFIX"]
    adjustments = Adjustments(Jobs(client, RedisStorage(client, prefix, 600), prefix=prefix, ttl_s=600,
                                   job_timeout_s=60, lease_s=5))
    record = AdjustmentRecord(id="b" * 32, job="c" * 32, owner="me", queue="default", status="running",
                              created_at=now(), worker="gone.1", request=AdjustRequest(transform=np.eye(4).tolist()))
    client.set(adjustments.key(record.id), record.model_dump_json(), ex=600)
    try:
        lost = adjustments.get(record.id)
        assert (lost.status, lost.error.code) == ("failed", "worker_lost")
        assert adjustments.get(record.id).status == "failed"  # stored so
    finally:
        client.delete(adjustments.key(record.id))
        client.close()


def test_drop_push_save_and_chain_on_the_adjusted_scene(api, worker):
    job_id = submit(api)
    job = succeeded(api, job_id)
    assert job["adjusted"] is None
    report = api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()
    answer = report["transform"]["matrix"]
    original_glb = api.client.get(f"/jobs/{job_id}/result.glb", headers=AUTH).content
    assert np.allclose(ball_in(original_glb)[0], answer, atol=1e-6)

    _refused_before_queueing(api, job_id, answer)
    _measured_where_the_run_left_it(api, job_id, answer)
    lifted = moved(answer, dx=0.1, dy=0.4)
    down = _dropped_back_into_contact(api, job_id, lifted)
    _pushed_and_dropped_beside_the_table(api, job_id)
    _saved_with_the_original_kept(api, job_id, lifted, down, report, original_glb)
    final = _saved_again(api, job_id, down, report, original_glb)
    chained_id, scene = _chained_on_the_adjusted_scene(api, job_id, final)
    _chained_job_adjusted(api, chained_id, scene)


def _refused_before_queueing(api, job_id: str, answer: list) -> None:
    """What the API refuses before queueing anything: a transform that is no rigid motion with a scale (a 3x3, a
    shear, a mirror, a NaN), a push with no direction or a zero one, an unknown settle, a transform that is no
    matrix; and the original of a job never adjusted."""
    sheared = moved(answer)
    sheared[0][1] += 0.5
    mirrored = (np.array(answer) @ np.diag([-1.0, 1, 1, 1])).tolist()
    for transform in (np.eye(3).tolist(), sheared, mirrored, moved(answer, dx=float("nan"))):
        assert error(post(api, job_id, {"transform": transform})) == (422, "invalid_transform", "transform")
    assert error(post(api, job_id, {"transform": answer, "settle": "push"})) == (422, "invalid_direction",
                                                                                   "direction")
    assert error(post(api, job_id, {"transform": answer, "settle": "push", "direction": [0, 0, 0]}))[:2] == (
        422, "invalid_direction")
    assert error(post(api, job_id, {"transform": answer, "settle": "fly"}))[:2] == (400, "invalid_request")
    assert error(post(api, job_id, {"transform": "up"}))[:2] == (400, "invalid_request")
    assert error(api.client.get(f"/jobs/{job_id}/original.glb", headers=AUTH)) == (404, "not_adjusted", None)


def _measured_where_the_run_left_it(api, job_id: str, answer: list) -> None:
    """The run's own transform, not settled: touching, no penetration past the search's threshold; the
    adjustment readable at its link by its owner only."""
    here = post(api, job_id, {"transform": answer})
    assert here.status_code == 200 and here.headers["Preference-Applied"] == "wait=60", here.text
    here = here.json()
    assert here["status"] == "succeeded" and here["result"]["settled"] is None, here
    assert np.allclose(here["result"]["transform"], answer, atol=1e-9)
    assert here["result"]["touching"] and here["result"]["penetration"] < 0.01
    assert api.client.get(here["link"], headers=AUTH).json() == here
    assert error(api.client.get(here["link"], headers=OTHERS)) == (404, "job_not_found", None)
    assert error(api.client.get(f"/jobs/{job_id}/adjust/{'d' * 32}", headers=AUTH))[:2] == (404,
                                                                                           "adjustment_not_found")


def _dropped_back_into_contact(api, job_id: str, lifted: list) -> np.ndarray:
    """Raised by hand (``lifted``) and dropped: straight down, back in contact, lower than it was lifted to; the
    dropped transform."""
    dropped = post(api, job_id, {"transform": lifted, "settle": "drop"}).json()
    result = dropped["result"]
    assert dropped["status"] == "succeeded" and result["settled"] and not result["on_floor"], dropped
    assert result["touching"] and result["moved"] > 0.5 and result["relation"]["holds"], result
    down = np.array(result["transform"])
    assert np.allclose(down[[0, 2], 3], np.array(lifted)[[0, 2], 3], atol=1e-6)  # straight down
    assert down[1, 3] < lifted[1][3] - 0.3
    ball = BALL.copy().apply_transform(down)
    gap, depth = sits_on_table(ball)
    assert gap < 0.02 and depth < 0.02, (gap, depth)
    return down


def _pushed_and_dropped_beside_the_table(api, job_id: str) -> None:
    """Beside the table at its height, pushed toward it: stops at its side; pushed away: nothing met, left as sent;
    dropped where nothing of the table is under it: rests where the table stands."""
    beside = moved(np.eye(4), dx=-1.2)
    pushed = post(api, job_id, {"transform": beside, "settle": "push", "direction": [1, 0, 0]}).json()["result"]
    assert pushed["settled"] and abs(pushed["transform"][0][3] - (-0.65)) < 0.03, pushed
    away = post(api, job_id, {"transform": beside, "settle": "push", "direction": [-1, 0, 0]}).json()["result"]
    assert away["settled"] is False and np.allclose(away["transform"], beside) and not away["touching"], away
    floor = post(api, job_id, {"transform": moved(np.eye(4), dx=1.5, dy=1.0), "settle": "drop"}).json()["result"]
    assert floor["settled"] and floor["on_floor"] and not floor["touching"], floor
    assert abs(BALL.copy().apply_transform(floor["transform"]).vertices[:, 1].min() - (-0.05)) < 0.01


def _saved_with_the_original_kept(api, job_id: str, lifted: list, down: np.ndarray, report: dict,
                                  original_glb: bytes) -> None:
    """Saved (through the Python client): the job's result is the adjusted scene (its GLB, its report, the job's
    ``adjusted``), the original kept."""
    with Client(api.url, api_key=KEY) as client:
        saved = client.adjust(job_id, lifted, settle="drop", save=True)
    assert saved["status"] == "succeeded" and saved["result"]["saved"], saved
    assert np.allclose(saved["result"]["transform"], down, atol=1e-9)  # the same settle, the same answer
    glb = api.client.get(f"/jobs/{job_id}/result.glb", headers=AUTH).content
    node, ball = ball_in(glb)
    assert np.allclose(node, down, atol=1e-6)  # the source node holds the saved transform
    gap, depth = sits_on_table(ball)
    assert gap < 0.02 and depth < 0.02, (gap, depth)
    assert api.client.get(f"/jobs/{job_id}/original.glb", headers=AUTH).content == original_glb
    assert api.client.get(f"/jobs/{job_id}/result.glb", params={"alternative": 0}, headers=AUTH).content == glb
    adjusted = api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()
    assert adjusted["adjusted"] is True and np.allclose(adjusted["transform"]["matrix"], down, atol=1e-9)
    assert adjusted["adjustment"]["original_transform"] == report["transform"]
    assert adjusted["adjustment"]["settle"] == "drop" and adjusted["prompt"] == report["prompt"]
    job = api.client.get(f"/jobs/{job_id}", headers=AUTH).json()
    assert job["adjusted"]["adjustment"] == saved["id"] and np.allclose(job["adjusted"]["transform"], down)


def _saved_again(api, job_id: str, down: np.ndarray, report: dict, original_glb: bytes) -> np.ndarray:
    """A second save moves it again; the original stays the run's own. The saved transform."""
    again = post(api, job_id, {"transform": moved(down, dz=0.1), "save": True}).json()
    assert again["result"]["saved"] and again["result"]["touching"], again
    assert api.client.get(f"/jobs/{job_id}/original.glb", headers=AUTH).content == original_glb
    assert api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()["adjustment"][
        "original_transform"] == report["transform"]
    return np.array(again["result"]["transform"])


def _chained_on_the_adjusted_scene(api, job_id: str, final: np.ndarray) -> tuple[str, trimesh.Scene]:
    """``target_job`` chaining builds on the adjusted scene: the ball stays where it was saved (``final``). The
    chained job and its result scene."""
    cube = trimesh.creation.box((0.1, 0.1, 0.1))
    chained = api.client.post("/align", headers=AUTH, files={"source": ("cube.glb", cube.export(file_type="glb"))},
                              data={"target_job": job_id, "prompt": "a cube on the ball", "options": json.dumps(FAST)})
    assert chained.status_code == 202, chained.text
    succeeded(api, chained.json()["id"])
    scene = trimesh.load(io.BytesIO(api.client.get(f"/jobs/{chained.json()['id']}/result.glb", headers=AUTH).content),
                         file_type="glb")
    assert set(scene.graph.nodes_geometry) == {"table", "ball", "cube"}  # the saved scene kept its names
    matrix, geometry = scene.graph["ball"]  # the adjusted job's source, one of the chained job's target objects
    placed = scene.geometry[geometry].copy().apply_transform(matrix)
    assert np.allclose(placed.bounds, BALL.copy().apply_transform(final).bounds, atol=1e-5)
    return chained.json()["id"], scene


def _chained_job_adjusted(api, chained_id: str, scene: trimesh.Scene) -> None:
    """The chained job adjusts the same way: its cube (the last of three objects) lifted, dropped and saved; the
    objects it was added to stay put."""
    cube_at = api.client.get(f"/jobs/{chained_id}/report.json", headers=AUTH).json()["transform"]["matrix"]
    redone = post(api, chained_id, {"transform": moved(cube_at, dy=0.3), "settle": "drop", "save": True}).json()
    assert redone["status"] == "succeeded" and redone["result"]["settled"], redone
    assert redone["result"]["touching"] and redone["result"]["penetration"] < 0.01, redone
    resaved = trimesh.load(io.BytesIO(api.client.get(f"/jobs/{chained_id}/result.glb", headers=AUTH).content),
                           file_type="glb")
    assert list(resaved.graph.nodes_geometry) == list(scene.graph.nodes_geometry)  # the same three nodes
    assert np.allclose(resaved.graph["cube"][0], redone["result"]["transform"], atol=1e-6)
    for kept in ("table", "ball"):  # the objects it was added to stay put
        assert np.allclose(resaved.graph[kept][0], scene.graph[kept][0])
