"""The web page, its job list and the offline docs, against the real service (private Redis, uvicorn, one
``ctp worker`` with ``random:tiny``), API keys on, and in a real browser: Debian's ``chromium`` driven by
Selenium through ``chromium-driver`` (``.ci/run`` installs both; Selenium Manager never downloads one).

Screenshots of the form, the progress and the result go to ``runs/screens/`` (git-ignored).
"""

from __future__ import annotations

import base64
import io
import json
import math
import os
import re
import shutil
import time

import numpy as np
import pytest
import trimesh

from tests.conftest import REPO, Api, park_worker, service_env, wait_for

KEY, OTHER = "page-key", "other-key"
AUTH = {"Authorization": f"Bearer {KEY}"}
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
SCREENS = REPO / "runs" / "screens"
BACKGROUND = (240, 242, 245)  # the viewer's clear colour (service/static/viewer.js)


@pytest.fixture(scope="module")
def env(private_redis):
    return service_env(private_redis.url, "page", api_keys=f"{KEY},{OTHER}", max_active_jobs=10)


def table_and_ball() -> tuple[bytes, bytes]:
    """A generated pair, as the user would upload it."""
    table = trimesh.creation.box((1.0, 0.1, 0.8))
    table.visual.vertex_colors = [150, 100, 60, 255]
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.15)
    ball.visual.vertex_colors = [200, 30, 30, 255]
    return table.export(file_type="glb"), ball.export(file_type="glb")


# -- HTTP: what the page is served from --------------------------------------------------------------

def test_page_static_files_and_docs_are_served_from_the_package(api):
    page = api.client.get("/")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    for url in re.findall(r'(?:src|href)="([^"#]+)"', page.text) + ["static/viewer.js"]:
        if not url.startswith("http"):
            assert api.client.get("/" + url).status_code == 200, url
    assert "http://" not in page.text.replace("http://www.w3.org", "") and "https://" not in page.text
    docs_assets = {"/docs": ("swagger-ui-bundle.js", "swagger-ui.css"), "/redoc": ("redoc.standalone.js",)}
    for docs, assets in docs_assets.items():
        html = api.client.get(docs).text
        urls = re.findall(r'(?:src|href)="([^"]+)"', html)
        assert urls and all(u.startswith("/static/vendor/") for u in urls), (docs, urls)  # nothing from a CDN
        for asset in assets:
            url = next(u for u in urls if u.endswith(asset))
            assert api.client.get(url).status_code == 200
    for licence in ("three/LICENSE", "swagger-ui/LICENSE", "redoc/LICENSE"):
        assert api.client.get(f"/static/vendor/{licence}").status_code == 200


def test_page_config_and_samples(api):
    config = api.client.get("/page/config").json()
    assert config["auth"] is True and "test" in config["presets"]
    assert config["bounds"]["restarts"] == {"minimum": 1, "maximum": 64}
    sample = config["samples"][0]
    glb = api.client.get(f"/samples/{sample['name']}/{sample['target_file']}")
    assert glb.status_code == 200 and glb.content[:4] == b"glTF"
    missing = api.client.get(f"/samples/{sample['name']}/nothing.glb")
    assert (missing.status_code, missing.json()["error"]["code"]) == (404, "not_found")


def test_page_asks_for_no_key_when_the_service_has_none(private_redis):
    open_service = Api(service_env(private_redis.url, "page-open"))
    try:
        assert open_service.client.get("/page/config").json()["auth"] is False
        assert open_service.client.get("/jobs").json() == {"jobs": [], "total": 0, "offset": 0, "limit": 20,
                                                           "next": None}
    finally:
        open_service.stop()


def test_job_list_is_the_callers_own_newest_first_and_paginated(api, env):
    target, source = table_and_ball()
    leave = park_worker(env)  # a live worker that consumes nothing: the jobs stay queued
    try:
        def submit(key: str) -> str:
            answer = api.client.post("/align", headers={"Authorization": f"Bearer {key}"},
                                     files={"target": ("t.glb", target), "source": ("s.glb", source)},
                                     data={"prompt": "a ball on a table", "options": json.dumps({"preset": "test"})})
            assert answer.status_code == 202, answer.text
            return answer.json()["id"]

        mine = [submit(OTHER) for _ in range(3)]
        theirs = submit(KEY)
        other = {"Authorization": f"Bearer {OTHER}"}
        first = api.client.get("/jobs", params={"limit": 2}, headers=other).json()
        assert [j["id"] for j in first["jobs"]] == mine[:0:-1] and first["total"] == 3
        rest = api.client.get(first["next"], headers=other).json()
        assert [j["id"] for j in rest["jobs"]] == mine[:1] and rest["next"] is None
        assert api.client.get("/jobs").status_code == 401
        bad = api.client.get("/jobs", params={"limit": 0}, headers=other)
        assert (bad.status_code, bad.json()["error"]["code"]) == (400, "invalid_request")
        for job_id, headers in [*((j, other) for j in mine), (theirs, AUTH)]:  # leave the worker to the browser test
            assert api.client.delete(f"/jobs/{job_id}", headers=headers).status_code == 200
    finally:
        leave()


# -- the browser -------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if not (os.access(CHROMIUM, os.X_OK) and os.access(CHROMEDRIVER, os.X_OK)):
        pytest.skip(f"no Chromium here ({CHROMIUM}, {CHROMEDRIVER}): apt-get install chromium chromium-driver")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    downloads = tmp_path_factory.mktemp("downloads")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader", "--window-size=1280,1400", "--disable-gpu-sandbox"):
        options.add_argument(arg)
    options.add_experimental_option("prefs", {"download.default_directory": str(downloads),
                                              "download.prompt_for_download": False})
    # A driver path in Service: Selenium skips Selenium Manager, which would otherwise download one.
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=options)
    driver.execute_cdp_cmd("Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)})
    driver.set_script_timeout(30)
    driver.downloads = downloads
    yield driver
    driver.quit()


def shoot(driver, name: str) -> None:
    SCREENS.mkdir(parents=True, exist_ok=True)
    driver.save_screenshot(str(SCREENS / f"{name}.png"))


def drop_file(driver, zone_id: str, name: str, data: bytes) -> None:
    """What a drag and drop from the desktop delivers: a drop event whose DataTransfer holds the file."""
    driver.execute_script("""
        const [zoneId, name, b64] = arguments;
        const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
        const transfer = new DataTransfer();
        transfer.items.add(new File([bytes], name));
        document.getElementById(zoneId).dispatchEvent(new DragEvent("drop", {dataTransfer: transfer, bubbles: true}));
    """, zone_id, name, base64.b64encode(data).decode())


def open_page(driver, api) -> None:
    """Load the page in a fresh tab state; keys are on, so it asks for one."""
    from selenium.webdriver.common.by import By

    driver.get(api.url + "/")
    driver.execute_script("sessionStorage.clear()")
    driver.get(api.url + "/")
    wait_for(lambda: driver.execute_script("return document.body.dataset.ready"), 20, "the page to start")
    assert driver.find_element(By.ID, "key-form").is_displayed()
    assert driver.find_element(By.ID, "key-state").text == "this service needs an API key"
    driver.find_element(By.ID, "api-key").send_keys(KEY)
    driver.find_element(By.CSS_SELECTOR, "#key-form button").click()
    wait_for(lambda: driver.find_element(By.ID, "key-state").text == "key set", 5, "the key to be taken")


def open_result(driver, api, job_id: str, shown=None, what: str = "the result") -> None:
    """``open_page``, then the job's row in the job list, until the 3D view holds its result (and ``shown``)."""
    from selenium.webdriver.common.by import By

    open_page(driver, api)
    opener = f"#jobs-body tr[data-id='{job_id}'] button"
    wait_for(lambda: driver.find_elements(By.CSS_SELECTOR, opener), 20, "the job list")
    driver.find_element(By.CSS_SELECTOR, opener).click()
    ready = lambda: driver.find_element(By.ID, "viewer").get_attribute("data-ready")  # noqa: E731
    wait_for(lambda: ready() and (shown is None or shown()), 60, what)


CANVAS_COLOURS = """
    const canvas = document.querySelector('#viewer canvas');
    const copy = Object.assign(document.createElement('canvas'), {width: canvas.width, height: canvas.height});
    const ctx = copy.getContext('2d');
    ctx.drawImage(canvas, 0, 0);
    const px = ctx.getImageData(0, 0, copy.width, copy.height).data;
    const [r0, g0, b0] = arguments[0];
    let total = 0, differ = 0, blue = 0, orange = 0;
    for (let i = 0; i < px.length; i += 4) {
      const [r, g, b] = [px[i], px[i + 1], px[i + 2]];
      total++;
      if (Math.abs(r - r0) + Math.abs(g - g0) + Math.abs(b - b0) > 30) differ++;
      if (b > r + 40 && b > g) blue++;
      if (r > b + 60 && g > b) orange++;
    }
    return {total, differ, blue, orange};
"""


def test_upload_follow_view_download_and_a_refused_upload(api, worker, browser, tmp_path):
    driver = browser
    open_page(driver, api)
    target, source = _example_then_own_files(driver, tmp_path)
    _previews_and_the_up(driver, target)
    _options_set(driver)
    job_id = _submitted_and_followed(driver)
    _result_viewed(driver)
    _downloaded_and_reopened(driver, api, job_id)
    _broken_upload_refused(driver, api, tmp_path, source)


def _example_then_own_files(driver, tmp_path) -> tuple[bytes, bytes]:
    """An example fills the form; then the user's own files replace it, one chosen, one dropped. The pair."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    find(By.CSS_SELECTOR, "[data-sample='apple-in-bowl']").click()  # an example fills the form
    wait_for(lambda: "bowl.glb" in find(By.ID, "chosen-target").text, 20, "the example's target")
    assert "apple.glb" in find(By.ID, "chosen-source").text
    assert find(By.ID, "prompt").get_attribute("value") == "an apple in a bowl"
    find(By.ID, "prompt").clear()
    for role in ("target", "source"):
        find(By.ID, f"name-{role}").clear()

    target, source = table_and_ball()  # then the user's own files replace it
    (tmp_path / "table.glb").write_bytes(target)
    find(By.ID, "file-target").send_keys(str(tmp_path / "table.glb"))
    drop_file(driver, "drop-source", "ball.glb", source)
    assert "ball.glb" in find(By.ID, "chosen-source").text
    return target, source


def _previews_and_the_up(driver, target: bytes) -> None:
    """Each input appears at once in its own small 3D view, with what the service makes of it (POST /inspect); the
    user flips the target's up (asked again, the arrows redrawn) and goes back to the file's."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    find = driver.find_element
    drawn = lambda: all(find(By.ID, f"preview-{r}").get_attribute("data-ready") == "1" for r in ("target", "source"))  # noqa: E731
    wait_for(drawn, 30, "both input previews drawn, with the up arrow")
    faces = len(trimesh.load(io.BytesIO(target), file_type="glb", force="mesh").faces)
    info = find(By.ID, "inspect-target").text
    assert f"{faces:,} faces" in info and "file's units" in info and "up: the file's" in info, info
    assert "every glTF file" in info and "front: the file's +z" in info, info
    colours = driver.execute_script(CANVAS_COLOURS.replace("#viewer canvas", "#preview-source canvas"), BACKGROUND)
    assert colours["differ"] > 0.02 * colours["total"], colours  # the ball is drawn
    find(By.ID, "flip-up-target").click()  # the user flips the up: asked again with up -y, the arrows redrawn
    wait_for(lambda: "up: -y as given" in find(By.ID, "inspect-target").text, 20, "the flipped up")
    assert find(By.ID, "up-target").get_attribute("value") == "-y"
    Select(find(By.ID, "up-target")).select_by_value("file")  # and back: the job runs in the file's frame
    wait_for(lambda: "every glTF file" in find(By.ID, "inspect-target").text, 20, "the file's up again")
    find(By.ID, "drop-target").location_once_scrolled_into_view  # noqa: B018
    shoot(driver, "previews")


def _options_set(driver) -> None:
    """The prompt, the test preset, a seed and two restarts."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    find = driver.find_element
    find(By.ID, "prompt").send_keys("a ball on top of a table")
    Select(find(By.ID, "opt-preset")).select_by_value("test")
    find(By.ID, "opt-seed").send_keys("3")
    find(By.ID, "opt-restarts").send_keys("2")
    shoot(driver, "form")


def _submitted_and_followed(driver) -> str:
    """Submitted: the progress panel follows the job to 100 %, then the readout, the job's guide and the 3D viewer.
    The job's id."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    find(By.ID, "submit").click()
    wait_for(lambda: find(By.ID, "progress").is_displayed(), 20, "the progress panel")
    job_id = find(By.ID, "job-id").text
    wait_for(lambda: find(By.ID, "steps").text or find(By.ID, "percent").text == "100 %", 120,
             "the first optimisation steps", interval_s=0.05)
    shoot(driver, "progress")
    wait_for(lambda: find(By.ID, "percent").text == "100 %", 240, "the progress bar at 100 %", interval_s=0.25)
    assert find(By.ID, "stage").text.lower() == "succeeded"
    quality = find(By.ID, "quality").text  # the readout, not the raw objective
    assert "'on' holds for" in quality and ("touching" in quality or "gap" in quality), quality
    assert find(By.ID, "guide").text == "guide: random:tiny"  # the job's guide (CTP_MODEL names one: no banner)
    assert not find(By.ID, "guide-banner").is_displayed()
    wait_for(lambda: find(By.ID, "viewer").get_attribute("data-ready"), 60, "the 3D viewer")
    return job_id


def _result_viewed(driver) -> None:
    """The WebGL canvas shows the scene, each object in its own colour when tinted; the result's facts."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    colours = driver.execute_script(CANVAS_COLOURS, BACKGROUND)
    assert colours["differ"] > 0.02 * colours["total"], colours  # the WebGL canvas shows the scene
    find(By.ID, "tint").click()  # each object in its own colour: blue target, orange source
    tinted = driver.execute_script(CANVAS_COLOURS, BACKGROUND)
    assert tinted["blue"] > 0.005 * tinted["total"] and tinted["orange"] > 0.0005 * tinted["total"], tinted
    assert [e.text for e in driver.find_elements(By.CSS_SELECTOR, "#parts label")][:2] == ["table", "ball"]
    assert find(By.ID, "result-prompt").text == '"a ball on top of a table"'
    facts = find(By.ID, "transform").text
    assert "position" in facts and ("° about" in facts or "not turned" in facts), facts
    assert "objective" not in facts and "quaternion" not in facts, facts
    assert "chose" in find(By.ID, "transform").text  # who ordered the poses: the guide, the geometry or both
    assert driver.execute_script("return document.getElementById('preview').naturalWidth") > 0
    find(By.ID, "result").location_once_scrolled_into_view  # noqa: B018 - scrolls for the screenshot
    shoot(driver, "result-tinted")
    find(By.ID, "tint").click()
    shoot(driver, "result")


def _downloaded_and_reopened(driver, api, job_id: str) -> None:
    """The GLB download is what the service serves; the job list reopens the result; the key travelled in a header
    only."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    find(By.CSS_SELECTOR, "[data-file='result.glb']").click()
    downloaded = driver.downloads / f"{job_id}-result.glb"
    wait_for(downloaded.exists, 20, "the GLB download")
    time.sleep(0.2)
    served = api.client.get(f"/jobs/{job_id}/result.glb", headers=AUTH).content
    assert downloaded.read_bytes() == served
    scene = trimesh.load(downloaded, file_type="glb")
    assert set(scene.graph.nodes_geometry) == {"table", "ball"}  # named by the uploads' file names

    rows = driver.find_elements(By.CSS_SELECTOR, f"#jobs-body tr[data-id='{job_id}']")
    assert rows and "succeeded" in rows[0].text
    rows[0].find_element(By.TAG_NAME, "button").click()  # reopen the result from the job list
    wait_for(lambda: find(By.ID, "viewer").get_attribute("data-ready") and not find(By.ID, "progress").is_displayed(),
             30, "the reopened result")
    # The key travelled in a header only: no URL the page fetched holds it.
    fetched = driver.execute_script("return performance.getEntriesByType('resource').map((e) => e.name)")
    assert fetched and not [u for u in fetched if KEY in u]


def _broken_upload_refused(driver, api, tmp_path, source: bytes) -> None:
    """A broken file: its preview says the refusal before any job, and the submit shows the API's own error."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    broken = tmp_path / "broken.glb"
    broken.write_bytes(b"glTF" + bytes(range(256)) * 4)
    find(By.ID, "file-target").send_keys(str(broken))
    wait_for(lambda: find(By.ID, "inspect-target").get_attribute("data-state") == "refused", 20,
             "the preview's refusal")
    assert find(By.ID, "inspect-target").text.startswith("mesh_unreadable: ")  # before any job
    find(By.ID, "submit").click()
    wait_for(lambda: find(By.ID, "error").is_displayed(), 20, "the error message")
    expected = api.client.post("/align", headers=AUTH, data={"prompt": "a ball on top of a table"},
                               files={"target": ("broken.glb", broken.read_bytes()), "source": ("ball.glb", source)})
    error = expected.json()["error"]
    assert (expected.status_code, error["field"]) == (422, "target")
    assert find(By.ID, "error").text == f'{error["code"]} target file "broken.glb" refused: {error["message"]}'
    find(By.ID, "error").location_once_scrolled_into_view  # noqa: B018
    shoot(driver, "refused")


def test_add_an_object_to_a_result_from_the_page(api, worker, browser, tmp_path):
    """"Add an object to this scene" on a result: the form takes that scene as the target (its preview shows it),
    the job goes out with ``target_job``, its result holds the scene's objects and the new one, and the job list
    shows it under the job it adds to."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    target, source = table_and_ball()
    first = api.client.post("/align", headers=AUTH,
                            files={"target": ("table.glb", target), "source": ("ball.glb", source)},
                            data={"prompt": "a ball on a table", "options": json.dumps({"preset": "test"})})
    first = first.json()["id"]
    status = lambda job_id: api.client.get(f"/jobs/{job_id}", headers=AUTH).json()["status"]  # noqa: E731
    wait_for(lambda: status(first) == "succeeded", 240, "the first job")

    driver, find = browser, browser.find_element
    open_result(driver, api, first, what="the first result")
    find(By.ID, "add-object").click()
    assert find(By.ID, "chosen-target").text == f"the scene of job {first[:8]} (its objects stay put)"
    wait_for(lambda: find(By.ID, "preview-target").get_attribute("data-ready") == "1", 30, "the scene's preview")
    cube = trimesh.creation.box((0.1, 0.1, 0.1))
    drop_file(driver, "drop-source", "cube.glb", cube.export(file_type="glb"))
    find(By.ID, "prompt").send_keys("a cube on the ball")
    Select(find(By.ID, "opt-preset")).select_by_value("test")
    shoot(driver, "add-object-form")
    find(By.ID, "submit").click()
    wait_for(lambda: find(By.ID, "percent").text == "100 %", 240, "the chained job", interval_s=0.25)
    assert find(By.ID, "stage").text.lower() == "succeeded"
    second = find(By.ID, "job-id").text
    job = api.client.get(f"/jobs/{second}", headers=AUTH).json()
    assert (job["target_job"], job["stages"]) == (first, 1)
    scene = trimesh.load(io.BytesIO(api.client.get(f"/jobs/{second}/result.glb", headers=AUTH).content),
                         file_type="glb")
    assert len(scene.graph.nodes_geometry) == 3  # the table and the ball, kept, and the cube
    wait_for(lambda: driver.find_elements(By.CSS_SELECTOR, f"#jobs-body tr[data-id='{second}']"), 20, "the new row")
    rows = [r.get_attribute("data-id") for r in driver.find_elements(By.CSS_SELECTOR, "#jobs-body tr")]
    assert rows.index(second) == rows.index(first) + 1  # under the job it adds to
    added = find(By.CSS_SELECTOR, f"#jobs-body tr[data-id='{second}']").text
    assert "↳ a cube on the ball" in added and f"added to the scene of {first[:8]}" in added
    find(By.ID, "result").location_once_scrolled_into_view  # noqa: B018
    shoot(driver, "add-object-result")


def test_choose_among_alternatives_from_the_page(api, worker, browser):
    """The result's strip of alternatives: a click shows that placement in the 3D view, and the GLB download is
    that one's (the same bytes as result.glb?alternative=k)."""
    from selenium.webdriver.common.by import By

    target, source = table_and_ball()
    answer = api.client.post("/align", headers=AUTH,
                             files={"target": ("table.glb", target), "source": ("ball.glb", source)},
                             data={"prompt": "a ball on a table",
                                   "options": json.dumps({"preset": "test", "restarts": 6})})
    job_id = answer.json()["id"]
    job = wait_for(lambda: (j := api.client.get(f"/jobs/{job_id}", headers=AUTH).json())["status"] == "succeeded"
                   and j, 240, "the job")
    assert len(job["alternatives"]) >= 2, job["alternatives"]

    driver, find = browser, browser.find_element
    open_result(driver, api, job_id, lambda: find(By.ID, "alternatives").is_displayed(),
                "the result and its alternatives")
    buttons = driver.find_elements(By.CSS_SELECTOR, "#alternatives button")
    assert len(buttons) == len(job["alternatives"]) and buttons[0].text.startswith("answer")
    assert "chosen" in buttons[0].get_attribute("class") and find(By.ID, "add-object").is_enabled()
    buttons[1].click()
    wait_for(lambda: find(By.ID, "viewer").get_attribute("data-alternative") == "1"
             and find(By.ID, "viewer").get_attribute("data-ready"), 30, "the second placement shown")
    assert "chosen" in buttons[1].get_attribute("class") and not find(By.ID, "add-object").is_enabled()
    report = api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()
    shown = report["alternatives"][1]["transform"]["translation"]
    assert ", ".join(f"{v:.3f}" for v in shown) in find(By.ID, "transform").text  # the facts follow the view
    find(By.ID, "result").location_once_scrolled_into_view  # noqa: B018
    shoot(driver, "alternative")
    find(By.CSS_SELECTOR, "[data-file='result.glb']").click()
    downloaded = driver.downloads / f"{job_id}-result-2.glb"
    wait_for(downloaded.exists, 20, "the alternative's GLB download")
    time.sleep(0.2)
    assert downloaded.read_bytes() == api.client.get(f"/jobs/{job_id}/result.glb", params={"alternative": 1},
                                                     headers=AUTH).content
    buttons[0].click()
    wait_for(lambda: find(By.ID, "viewer").get_attribute("data-alternative") == "0", 30, "the answer again")
    assert find(By.ID, "add-object").is_enabled()


def test_cancel_from_the_page(api, worker, browser):
    """Watch a run optimise (the default preset, one of the examples), then cancel a longer one.

    The default run asks for 48 restarts (the search keeps at most its 12 fine candidates, plus the tile stage's):
    its search's stage line has no phase, and the restart count is the planned one, then the one refined, nothing
    else. Its refinement lasts a fraction of a second, too short for a click to land in, so the run cancelled is
    the descent preset's (120 steps from random starts, minutes on a CPU)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    driver, find = browser, browser.find_element
    open_page(driver, api)
    find(By.CSS_SELECTOR, "[data-sample='cup-on-table']").click()
    wait_for(lambda: "table.glb" in find(By.ID, "chosen-target").text, 20, "the example's files")
    Select(find(By.ID, "opt-preset")).select_by_value("default")
    find(By.ID, "opt-restarts").send_keys("48")
    find(By.ID, "submit").click()
    seen = []  # (stage, steps) lines as the run goes

    def refining() -> bool:
        seen.append((find(By.ID, "stage").text.lower(), find(By.ID, "steps").text))
        return seen[-1][0].startswith("refine") and find(By.ID, "eta").text.startswith("about") and find(
            By.ID, "quality").text

    wait_for(refining, 180, "the refinement with an ETA and a readout", interval_s=0.1)
    searching = [stage for stage, _ in seen if stage.startswith("search")]
    assert searching and not [s for s in searching if "phase" in s], seen  # the search has no phase
    counts = {int(m.group(1)) for _, steps in seen if (m := re.search(r"(\d+) restarts", steps))}
    refined = int(re.search(r"(\d+) restarts", find(By.ID, "steps").text).group(1))
    assert refined > 8 and counts <= {refined, 48, 48 + 1}, seen  # asked for 48 (+ the tile stage's), then what it kept
    shoot(driver, "progress-running")
    wait_for(lambda: find(By.ID, "percent").text == "100 %", 240, "the default run to finish", interval_s=0.25)
    Select(find(By.ID, "opt-preset")).select_by_value("descent")
    find(By.ID, "opt-restarts").clear()
    find(By.ID, "submit").click()
    wait_for(lambda: find(By.ID, "stage").text.lower().startswith("refine") and find(By.ID, "steps").text, 180,
             "the descent's first steps", interval_s=0.1)
    find(By.ID, "cancel").click()
    wait_for(lambda: find(By.ID, "stage").text.lower() == "canceled", 120, "the job to stop")
    assert "canceled" in find(By.ID, "error").text and int(find(By.ID, "percent").text.split()[0]) < 100
    shoot(driver, "canceled")


def test_docs_render_offline(api, browser):
    """Swagger UI and ReDoc draw the schema from the vendored scripts (CI has no internet either)."""
    from selenium.webdriver.common.by import By

    for path, selector in {"/docs": ".swagger-ui .opblock", "/redoc": ".redoc-wrap [data-section-id]"}.items():
        browser.get(api.url + path)
        wait_for(lambda sel=selector: browser.find_elements(By.CSS_SELECTOR, sel), 30, f"{path} to render")
        assert "/jobs" in browser.find_element(By.TAG_NAME, "body").text


HANDLE = """
    // Where one of the move handle's arrows is on screen (viewport pixels): TransformControls draws its gizmo at
    // the pivot, sized by its distance to the camera (its own formula), each arrow's picker from 0 to 0.6 of that.
    const axis = arguments[0];
    const box = document.getElementById('viewer');
    const v = box.viewer, cam = v.camera, rect = box.querySelector('canvas').getBoundingClientRect();
    v.model.updateMatrixWorld(true);
    const origin = v.pivot.getWorldPosition(v.pivot.position.clone());
    const size = origin.distanceTo(cam.position) * Math.min(1.9 * Math.tan(Math.PI * cam.fov / 360) / cam.zoom, 7)
      * v.handles.size / 4;
    const at = (t) => {
      const p = origin.clone();
      p[axis] += t * size;
      p.project(cam);
      return [rect.left + (p.x + 1) / 2 * rect.width, rect.top + (1 - p.y) / 2 * rect.height];
    };
    return {grab: at(0.45), tip: at(1.0)};
"""
SOURCE_MATRIX = "return document.getElementById('viewer').viewer.sourceMatrix()"


def drag_handle(driver, axis: str, pixels: int) -> None:
    """A real drag with the mouse: hover the move handle's arrow of ``axis`` ("x", "y", "z"), press, move
    ``pixels`` along it as it shows on screen, in steps, release."""
    from selenium.webdriver.common.actions.action_builder import ActionBuilder

    where = driver.execute_script(HANDLE, axis)
    (x, y), (tip_x, tip_y) = where["grab"], where["tip"]
    length = math.hypot(tip_x - x, tip_y - y)
    assert length > 10, where  # the arrow shows from this view, not end-on
    actions = ActionBuilder(driver)
    pointer = actions.pointer_action
    pointer.move_to_location(round(x), round(y)).pause(0.3).pointer_down().pause(0.2)
    for step in range(1, 11):
        pointer.move_to_location(round(x + (tip_x - x) * pixels * step / 10 / length),
                                 round(y + (tip_y - y) * pixels * step / 10 / length)).pause(0.05)
    pointer.pointer_up()
    actions.perform()


def test_adjust_the_source_by_hand_drop_it_and_save(api, worker, browser):
    """The result's handles: a real mouse drag of the move handle's up arrow lifts the source, "Push along view"
    and "Reset" go and come back, a drag of one scale axis scales it evenly, then dragged along the table and up,
    "Drop to contact" lowers it onto the table (the worker's settle) and "Save" stores it: the job's result.glb
    has the source node at the saved transform, touching the table (measured on the GLB with trimesh), and
    original.glb is the run's own GLB. Screenshots of each step in runs/screens/adjust-*.png."""
    job_id, report, original = _a_ball_on_the_table(api)
    driver = browser
    shown = _handles_shown(driver, api, job_id, report)
    _lifted_pushed_and_reset(driver, shown)
    _scaled_evenly(driver, shown)
    dropped = _dragged_and_dropped(driver, shown)
    _saved(driver)
    _saved_scene_downloaded(driver, api, job_id, dropped, original)


def _adjust_state(driver) -> str:
    from selenium.webdriver.common.by import By

    return driver.find_element(By.ID, "adjust-state").get_attribute("data-state")


def _a_ball_on_the_table(api) -> tuple[str, dict, bytes]:
    """A job that puts the ball on the table (the relation holds: dropping it lands it there again): its id, its
    report and its GLB."""
    target, source = table_and_ball()
    answer = api.client.post("/align", headers=AUTH,
                             files={"target": ("table.glb", target), "source": ("ball.glb", source)},
                             data={"prompt": "a ball on top of a table",
                                   "options": json.dumps({"preset": "test", "seed": 3})})
    job_id = answer.json()["id"]
    wait_for(lambda: api.client.get(f"/jobs/{job_id}", headers=AUTH).json()["status"] == "succeeded", 240, "the job")
    report = api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()
    assert report["relation"]["holds"], report["relation"]  # the ball on the table: dropping it lands it there again
    original = api.client.get(f"/jobs/{job_id}/result.glb", headers=AUTH).content
    return job_id, report, original


def _handles_shown(driver, api, job_id: str, report: dict) -> np.ndarray:
    """The result opened with its handles, nothing to save yet; the source as the report places it (the matrix
    shown)."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    open_result(driver, api, job_id)
    assert find(By.ID, "adjust").is_displayed() and not find(By.ID, "adjust-save").is_enabled()
    shown = np.array(driver.execute_script(SOURCE_MATRIX))
    assert np.allclose(shown, report["transform"]["matrix"], atol=1e-5)  # the GLB's source node, as the report says
    find(By.CSS_SELECTOR, "input[name=adjust-mode][value=translate]").click()
    find(By.ID, "viewer").location_once_scrolled_into_view  # noqa: B018 - the drag needs it on screen
    shoot(driver, "adjust-handles")
    return shown


def _lifted_pushed_and_reset(driver, shown: np.ndarray) -> None:
    """A drag of the up arrow lifts the source along it only (the facts follow); a push along the view settles it
    or meets nothing; "Reset" puts it back."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    drag_handle(driver, "y", 120)
    wait_for(lambda: _adjust_state(driver) == "moved", 10, "the drag to move the source")
    lifted = np.array(driver.execute_script(SOURCE_MATRIX))
    assert lifted[1, 3] > shown[1, 3] + 0.05, (lifted, shown)  # up, the arrow's axis
    assert np.allclose(lifted[[0, 2], 3], shown[[0, 2], 3], atol=1e-6) and np.allclose(lifted[:3, :3], shown[:3, :3])
    assert f"{lifted[1, 3]:.3f}" in find(By.ID, "transform").text  # the facts follow the source
    shoot(driver, "adjust-dragged")

    find(By.ID, "adjust-push").click()  # the way the view looks: onto something, or nothing met
    wait_for(lambda: _adjust_state(driver) in ("settled", "unsettled"), 60, "the push")
    find(By.ID, "adjust-reset").click()
    assert _adjust_state(driver) == "idle" and np.allclose(driver.execute_script(SOURCE_MATRIX), shown, atol=1e-6)


def _scaled_evenly(driver, shown: np.ndarray) -> None:
    """A drag of one axis of the scale handle scales the source by one factor on every axis; then reset, back to
    moving."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    find(By.CSS_SELECTOR, "input[name=adjust-mode][value=scale]").click()
    drag_handle(driver, "x", 40)  # one axis of the scale handle: the page keeps the scale one factor
    wait_for(lambda: _adjust_state(driver) == "moved", 10, "the scale drag")
    linear = np.array(driver.execute_script(SOURCE_MATRIX))[:3, :3] @ np.linalg.inv(shown[:3, :3])
    factors = np.linalg.svd(linear, compute_uv=False)
    assert abs(factors[0] - 1) > 0.05 and np.allclose(factors, factors[0], rtol=1e-6), factors
    find(By.ID, "adjust-reset").click()
    find(By.CSS_SELECTOR, "input[name=adjust-mode][value=translate]").click()


def _dragged_and_dropped(driver, shown: np.ndarray) -> np.ndarray:
    """Dragged along the table and up off it, then "Drop to contact": straight down onto the table, touching, at a
    placement of its own. The dropped matrix."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    drag_handle(driver, "x", 60)  # along the table, then up off it
    drag_handle(driver, "y", 120)
    wait_for(lambda: _adjust_state(driver) == "moved", 10, "the second drag")
    lifted = np.array(driver.execute_script(SOURCE_MATRIX))
    assert lifted[0, 3] > shown[0, 3] + 0.03 and lifted[1, 3] > shown[1, 3] + 0.05, (lifted, shown)
    find(By.ID, "adjust-drop").click()
    wait_for(lambda: _adjust_state(driver) in ("settled", "unsettled", "failed"), 60, "the drop")
    line = find(By.ID, "adjust-state").text
    assert _adjust_state(driver) == "settled" and line.startswith("dropped - touching - "), line
    dropped = np.array(driver.execute_script(SOURCE_MATRIX))
    assert dropped[1, 3] < lifted[1, 3] - 0.03 and np.allclose(dropped[[0, 2], 3], lifted[[0, 2], 3], atol=1e-5)
    assert not np.allclose(dropped, shown, atol=0.03)  # a placement of its own, not the run's
    shoot(driver, "adjust-dropped")
    return dropped


def _saved(driver) -> None:
    """The "Save" button: the saved result shown, said adjusted, with the original to download."""
    from selenium.webdriver.common.by import By

    find = driver.find_element
    find(By.ID, "adjust-save").click()
    wait_for(lambda: _adjust_state(driver) in ("saved", "failed"), 60, "the save")
    assert _adjust_state(driver) == "saved", find(By.ID, "adjust-state").text
    wait_for(lambda: find(By.ID, "viewer").get_attribute("data-ready"), 30, "the saved result shown")
    assert "adjusted" in find(By.ID, "transform").text
    assert find(By.CSS_SELECTOR, "[data-file='original.glb']").is_displayed()
    find(By.ID, "result").location_once_scrolled_into_view  # noqa: B018
    shoot(driver, "adjust-saved")


def downloaded_glb(driver, api, job_id: str) -> trimesh.Scene:
    """The result GLB the page's download button saves, checked to be the API's, as a scene."""
    from selenium.webdriver.common.by import By

    driver.find_element(By.CSS_SELECTOR, "[data-file='result.glb']").click()
    downloaded = driver.downloads / f"{job_id}-result.glb"
    wait_for(downloaded.exists, 20, "the GLB download")
    time.sleep(0.2)
    glb = downloaded.read_bytes()
    assert glb == api.client.get(f"/jobs/{job_id}/result.glb", headers=AUTH).content
    return trimesh.load(io.BytesIO(glb), file_type="glb")


def _saved_scene_downloaded(driver, api, job_id: str, dropped: np.ndarray, original: bytes) -> None:
    """The page's download is the saved scene: its source node at the dropped transform, touching the table
    (measured on the GLB with trimesh); original.glb is the run's own, the report says adjusted."""
    scene = downloaded_glb(driver, api, job_id)  # the page's download is the saved scene
    node, geometry = scene.graph["ball"]
    assert np.allclose(node, dropped, atol=1e-5)  # the source node holds the saved transform
    ball = scene.geometry[geometry].copy().apply_transform(node)
    table = scene.geometry[scene.graph["table"][1]].copy().apply_transform(scene.graph["table"][0])
    inside = float(trimesh.proximity.signed_distance(table, ball.vertices).max())  # > 0: a ball vertex in the table
    diagonal = float(np.linalg.norm(ball.extents))
    assert -0.02 * diagonal < inside < 0.02 * diagonal, inside  # touching: no gap, no penetration past 2 %
    assert api.client.get(f"/jobs/{job_id}/original.glb", headers=AUTH).content == original
    assert api.client.get(f"/jobs/{job_id}/report.json", headers=AUTH).json()["adjusted"] is True
