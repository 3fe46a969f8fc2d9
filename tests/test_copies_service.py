"""Several copies through the HTTP service (issue 41): the job options ``count`` and ``arrangement``, the
count's limit refused before queueing, and a job end to end (one GLB node per copy, the report's copies)."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

from tests.conftest import service_env, wait_for
from tests.test_service import BOX, FAST, glb, submit

SMALL_BOX = glb(trimesh.creation.box((0.3, 0.5, 0.3)))


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "copies", max_active_jobs=50)


@pytest.mark.parametrize(("options", "code"), [
    ({**FAST, "count": 13}, "count_out_of_range"),
    ({**FAST, "count": 0}, "count_out_of_range"),
    ({**FAST, "count": 2, "arrangement": "circle"}, "invalid_arrangement"),
])
def test_a_bad_count_or_arrangement_is_refused_before_queueing(api, options, code):
    answer = submit(api, target=("table.glb", BOX), source=("chair.glb", SMALL_BOX), prompt="chairs by the table",
                    options=options)
    assert answer.status_code == 422, answer.text
    assert answer.json()["error"]["code"] == code


def test_four_copies_around_end_to_end(api, worker):
    options = {**FAST, "lambda_clip": 0.0, "arrangement": "around"}
    accepted = submit(api, target=("table.glb", glb(trimesh.creation.box((1.2, 0.75, 0.8)))),
                      source=("chair.glb", SMALL_BOX), prompt="four chairs around the table", options=options)
    assert accepted.status_code == 202, accepted.text
    links = accepted.json()["links"]
    job = wait_for(lambda: (j := api.client.get(links["self"]).json())["status"] in ("succeeded", "failed") and j,
                   120, "the copies job")
    assert job["status"] == "succeeded", job
    assert (job["count"], job["arrangement"]) == (4, "around")
    scene = trimesh.load(io.BytesIO(api.client.get(links["result"]).content), file_type="glb")
    report = api.client.get(links["report"]).json()
    assert [c["name"] for c in report["copies"]] == ["chair_1", "chair_2", "chair_3", "chair_4"]
    for c in report["copies"]:
        np.testing.assert_allclose(scene.graph[c["name"]][0], c["transform"]["matrix"], atol=1e-5)
        assert c["relation"]["holds"] is True
    assert report["metrics"]["all_hold"] is True and report["metrics"]["none_intersect"] is True
    # adjust one copy at a time: copy 2 lifted, dropped back to the floor, saved; the others stay where they are
    lifted = np.array(report["copies"][1]["transform"]["matrix"])
    lifted[1, 3] += 0.5
    for body in ({"transform": lifted.tolist()}, {"transform": lifted.tolist(), "copy_index": 5}):
        refused = api.client.post(f"{links['self']}/adjust", json=body)
        assert (refused.status_code, refused.json()["error"]["code"]) == (422, "invalid_copy"), refused.text
    body = {"transform": lifted.tolist(), "copy_index": 2, "settle": "drop", "save": True}
    saved = api.client.post(f"{links['self']}/adjust", json=body, headers={"Prefer": "wait=60"})
    assert saved.status_code == 200 and saved.json()["status"] == "succeeded", saved.text
    assert abs(saved.json()["result"]["transform"][1][3] - report["copies"][1]["transform"]["matrix"][1][3]) < 0.01
    after = api.client.get(links["report"]).json()
    assert after["adjusted"] is True and after["adjustment"]["copy"] == 2 and after["copies"][1]["adjusted"] is True
    assert after["copies"][1]["original_transform"] == report["copies"][1]["transform"]
    assert [c["transform"] for i, c in enumerate(after["copies"]) if i != 1] == [
        c["transform"] for i, c in enumerate(report["copies"]) if i != 1]
    assert after["metrics"]["count"] == 4 and after["copies"][1]["relation"]["name"] == "beside+facing"
    again = trimesh.load(io.BytesIO(api.client.get(links["result"]).content), file_type="glb")
    for c in after["copies"]:
        np.testing.assert_allclose(again.graph[c["name"]][0], c["transform"]["matrix"], atol=1e-5)
