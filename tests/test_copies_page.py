"""The page with a job of several copies (issue 41): the facts list each copy and the set, the copy select puts
the handles on one copy at a time, and a drop then a save of copy 2 is the job's result (the other copies stay)."""

from __future__ import annotations

import json

import numpy as np
import trimesh

from tests.conftest import wait_for
from tests.test_page import AUTH, SOURCE_MATRIX, browser, env, open_result  # noqa: F401 - the page's fixtures


def test_adjust_one_copy_at_a_time_from_the_page(api, worker, browser):  # noqa: F811
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    table, chair = (trimesh.exchange.gltf.export_glb(trimesh.Scene(trimesh.creation.box(e)))
                    for e in ((1.2, 0.75, 0.8), (0.3, 0.5, 0.3)))
    files = {"target": ("table.glb", table), "source": ("chair.glb", chair)}
    answer = api.client.post("/align", headers=AUTH, files=files,
                             data={"prompt": "three chairs around the table",
                                   "options": json.dumps({"preset": "test", "lambda_clip": 0.0})})
    job_id = answer.json()["id"]
    wait_for(lambda: api.client.get(f"/jobs/{job_id}", headers=AUTH).json()["status"] == "succeeded", 120, "the job")
    report = api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()

    driver, find = browser, browser.find_element
    open_result(driver, api, job_id)
    facts = find(By.ID, "transform").text
    assert "3 (around)" in facts and "3 of 3 hold; none intersect" in facts and "chair_2" in facts, facts
    assert find(By.ID, "adjust").is_displayed() and find(By.ID, "adjust-copy-label").is_displayed()
    select = Select(find(By.ID, "adjust-copy"))
    assert [o.text for o in select.options] == ["chair_1", "chair_2", "chair_3"]
    assert np.allclose(driver.execute_script(SOURCE_MATRIX), report["copies"][0]["transform"]["matrix"], atol=1e-5)
    select.select_by_visible_text("chair_2")
    assert np.allclose(driver.execute_script(SOURCE_MATRIX), report["copies"][1]["transform"]["matrix"], atol=1e-5)

    state = lambda: find(By.ID, "adjust-state").get_attribute("data-state")  # noqa: E731
    find(By.ID, "adjust-drop").click()  # on the floor already: it stays there, settled
    wait_for(lambda: state() in ("settled", "unsettled", "failed"), 60, "the drop")
    assert state() == "settled", find(By.ID, "adjust-state").text
    find(By.ID, "adjust-save").click()
    wait_for(lambda: state() in ("saved", "failed"), 60, "the save")
    assert state() == "saved", find(By.ID, "adjust-state").text
    after = api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()
    assert after["adjustment"]["copy"] == 2 and after["copies"][1]["adjusted"] is True
    assert [c["transform"] for c in (after["copies"][0], after["copies"][2])] == [
        c["transform"] for c in (report["copies"][0], report["copies"][2])]
