"""The page's scene from one sentence (issue 49): several meshes and one description read into a plan shown as a
list, one step corrected by hand, the corrected plan placed as one job, and the result's facts listing every
relation judged again on the final scene."""

from __future__ import annotations

from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select

from tests.conftest import wait_for
from tests.test_compose import _bench, _box
from tests.test_page import AUTH, browser, env, open_page  # noqa: F401 - the page's fixtures


def test_read_a_plan_correct_a_step_and_place_the_scene(api, worker, browser, tmp_path):  # noqa: F811
    driver, find = browser, browser.find_element
    meshes = {"workbench": _bench(), "toolbox": _box(0.45, 0.25, 0.2), "stool": _box(0.5, 0.45, 0.35)}
    paths = []
    for name, mesh in meshes.items():
        mesh.export(tmp_path / f"{name}.glb")
        paths.append(str(tmp_path / f"{name}.glb"))
    open_page(driver, api)
    find(By.ID, "scene-files").send_keys("\n".join(paths))
    find(By.ID, "scene-prompt").send_keys("a toolbox on the workbench and a metronome on it")
    find(By.ID, "scene-read").click()  # a metronome has no mesh: the reader's error, nothing listed
    wait_for(lambda: find(By.ID, "error").is_displayed(), 10, "the error")
    assert "unknown_object" in find(By.ID, "error").text and "metronome" in find(By.ID, "error").text
    assert not find(By.ID, "scene-place").is_enabled()

    find(By.ID, "scene-prompt").clear()
    find(By.ID, "scene-prompt").send_keys("put the toolbox on the workbench; a stool to its left")
    find(By.ID, "scene-read").click()
    rows = lambda: find(By.ID, "scene-plan").find_elements(By.CSS_SELECTOR, "li[data-step]")  # noqa: E731
    wait_for(lambda: len(rows()) == 2, 10, "the plan")
    assert find(By.ID, "scene-plan").text.startswith("workbench stays put")
    assert [r.find_element(By.CLASS_NAME, "step-name").text for r in rows()] == ["toolbox (on)", "stool (left)"]
    assert [r.find_element(By.CLASS_NAME, "step-support").text for r in rows()] == [
        "stands on workbench", "stands on floor"]  # each step's support
    corrected = rows()[1].find_element(By.CLASS_NAME, "step-prompt")  # the person moves the stool to the right
    corrected.clear()
    corrected.send_keys("a stool to the right of the workbench")
    Select(find(By.ID, "opt-preset")).select_by_value("test")
    find(By.ID, "scene-place").click()

    wait_for(lambda: find(By.ID, "result").is_displayed(), 180, "the scene's result")
    job_id = find(By.ID, "result-id").text
    report = api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()
    assert [s["prompt"] for s in report["stages"]] == ["the toolbox on the workbench",
                                                        "a stool to the right of the workbench"]
    assert [r["relation"] for r in report["whole"]["relations"]] == ["on", "right"]
    facts = find(By.ID, "transform").text
    assert "relations hold" in facts and "stool right workbench" in facts, facts
