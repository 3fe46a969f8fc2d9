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
    adjust = api.client.post(f"{links['self']}/adjust", json={"transform": report["copies"][0]["transform"]["matrix"]})
    assert (adjust.status_code, adjust.json()["error"]["code"]) == (409, "not_adjustable")
