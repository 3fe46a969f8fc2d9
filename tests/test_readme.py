"""The documentation's commands, run as they stand (read from the pages, never a copy): the Quick start's
``ctp align`` on the generated sample pair, the curl walk-through and the Python client against a real
``ctp serve``, and the command-line synopsis, which must be what the parsers accept; and the service's
settings table, which must name every setting once.

Each block is marked in the Markdown (``<!-- readme-test:MARKER -->`` before a fenced block, the synopsis
between ``<!-- synopsis:start ... -->`` and ``<!-- synopsis:end -->``) and is looked up in README.md and
docs/*.md together, so a block can move between pages without touching this file; a marker that is missing,
or found in two places, fails with the pages named.

Two things are supplied around the text, because a test cannot do them itself: ``make install`` (these
tests already run in the venv it built; the line is checked to be that call and nothing else) and the
service the README starts in another terminal with ``make serve``, which here is ``ctp serve`` with default
settings on a free port (the only change to the commands: ``127.0.0.1:8000`` becomes that port, so parallel
runs cannot collide). Both run as on a fresh machine: no network, no weights (the session's Hugging Face cache
is empty, ``tests/conftest.py``), so model ``auto`` runs them without a guide, and they say so.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys

import httpx
import pytest
import trimesh

from ctp.cli import main, synopsis
from ctp.cmd_serve import stop_processes
from ctp_core.io.examples import get_example
from service.embedded import free_port
from tests.conftest import REPO, service_env, wait_for

PAGES = {path.relative_to(REPO).as_posix(): path.read_text()
         for path in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]}


def only_one(pattern: str, what: str) -> re.Match:
    """The one match of ``pattern`` over README.md and docs/*.md; missing or found twice fails, naming the pages."""
    found = [(page, m) for page, text in PAGES.items() for m in re.finditer(pattern, text, re.S)]
    assert found, f"no page has {what} (looked in {', '.join(PAGES)})"
    assert len(found) == 1, f"{what} is in more than one place: {', '.join(page for page, _ in found)}"
    return found[0][1]


def block(marker: str) -> str:
    """The fenced code block after ``<!-- readme-test:MARKER -->``, wherever that page is."""
    tag = f"<!-- readme-test:{marker} -->"
    only_one(re.escape(tag), tag)
    return only_one(rf"{re.escape(tag)}\s*```\w*\n(.*?)```", f"a code block after {tag}").group(1)


def bash(script: str, cwd, env) -> subprocess.CompletedProcess:
    run = subprocess.run(["bash", "-euo", "pipefail", "-c", script], cwd=cwd, env=env, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, f"stdout:\n{run.stdout}\nstderr:\n{run.stderr}"
    return run


def readme_env(tmp_path) -> dict[str, str]:
    """A checkout-like folder: ``.venv/bin/ctp`` is this interpreter's ``ctp`` on this tree."""
    venv_bin = tmp_path / ".venv" / "bin"
    venv_bin.mkdir(parents=True)
    (venv_bin / "ctp").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m ctp "$@"\n')
    (venv_bin / "ctp").chmod(0o755)
    env = {k: v for k, v in os.environ.items() if not k.startswith("CTP_") and k != "REDIS_URL"}
    return {**env, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE"}


def test_quick_start_align_runs_as_written(tmp_path):
    # `make install` has been done: it made the venv these tests run in. Any other make call fails here.
    preamble = 'make() { [ "$*" = install ]; }\n'
    bash(preamble + block("cli"), tmp_path, readme_env(tmp_path))
    scene = trimesh.load(tmp_path / "try" / "scene.glb", force="scene")
    assert set(scene.geometry) == {"table", "cup"}  # the names given
    report = json.loads((tmp_path / "try" / "report.json").read_text())
    assert (report["hparams"]["target_name"], report["hparams"]["source_name"]) == ("table", "cup")
    assert report["guide"] == "none" and "not in the Hugging Face cache" in report["guide_why"]  # no weights
    assert (tmp_path / "try" / "preview.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.skipif(shutil.which("curl") is None, reason="the walk-through needs curl, which is not installed")
def test_service_walk_through_and_client_run_as_written(tmp_path):
    get_example("cup-on-table").write(tmp_path / "try")  # what the Quick start's `ctp example --dir try` wrote
    port = free_port()
    env = {**service_env("unused", "ctp"), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    del env["REDIS_URL"], env["CTP_MODEL"], env["CTP_RUNTIME"]  # as in `make serve`: the default settings
    log = open(tmp_path / "serve.log", "wb")  # noqa: SIM115 - closed below
    serve = subprocess.Popen([sys.executable, "-m", "ctp", "serve", "--port", str(port)], env=env, cwd=REPO,
                             stdout=log, stderr=subprocess.STDOUT)
    try:
        def ready():
            try:
                return httpx.get(f"http://127.0.0.1:{port}/readyz").status_code == 200
            except httpx.TransportError:
                return False

        wait_for(ready, 120, "ctp serve to be ready", interval_s=0.5)
        here = {**readme_env(tmp_path), "PATH": f"{os.path.dirname(sys.executable)}:{os.environ['PATH']}"}
        run = bash(block("service").replace("127.0.0.1:8000", f"127.0.0.1:{port}"), tmp_path, here)
        job = json.loads((tmp_path / "job.json").read_text())
        assert job["status"] == "queued"
        ready = json.JSONDecoder().raw_decode(run.stdout)[0]  # the first answer: /readyz
        assert (ready["status"], ready["guide"], ready["get_model"]) == (
            "ready", "none", "ctp models pull openai/clip-vit-base-patch32")
        assert '"guide":"none"' in run.stdout  # the job says it ran without a guide
        assert "event: end" in run.stdout and '"status":"succeeded"' in run.stdout
        assert '"code":"job_finished"' in run.stdout  # the last line: cancel of the ended job
        served = trimesh.load(tmp_path / "try" / "served.glb", force="scene")
        assert set(served.geometry) == {"table", "cup"}
        assert '"target_name": "table"' in run.stdout  # the report says which names the priors read

        client = subprocess.run([sys.executable, "-c", block("client").replace("127.0.0.1:8000", f"127.0.0.1:{port}")],
                                cwd=tmp_path, env=here, capture_output=True, text=True, timeout=300)
        assert client.returncode == 0, client.stderr
        assert client.stdout.strip().splitlines()[-1] == "succeeded"
        assert trimesh.load(tmp_path / "try" / "client.glb", force="scene").geometry
    finally:
        stop_processes([serve], grace_s=40)
        log.close()


def test_synopsis_is_what_the_parsers_accept():
    only_one(re.escape("<!-- synopsis:start"), "<!-- synopsis:start")
    found = only_one(r"<!-- synopsis:start.*?-->\s*```\n(.*?)```\s*<!-- synopsis:end -->", "the synopsis block")
    assert found.group(1).rstrip() == synopsis(), (
        "the synopsis is stale: paste into its page the output of "
        'python -c "from ctp.cli import synopsis; print(synopsis())"')


def test_priors_needs_no_prompt(capsys):
    assert main(["priors", "--target", "table", "--source", "cup"]) == 0
    assert json.loads(capsys.readouterr().out)["penetration"] is False


def test_every_setting_is_in_the_settings_table_once():
    from service.settings import Settings

    rows = [row for text in PAGES.values() for row in re.findall(r"^\| `((?:CTP_)?[A-Z0-9_]+)` \|", text, re.M)]
    names = ["REDIS_URL" if n == "redis_url" else f"CTP_{n.upper()}" for n in Settings.model_fields]
    assert sorted(rows) == sorted(names), "the settings table (docs/service.md) and service/settings.py disagree"


def test_relative_links_point_at_files_and_headings():
    # The pages link each other and the repository with paths relative to their own folder; an anchor must be one
    # of the target page's headings, slugged as GitHub does.
    def anchors(page: str) -> set[str]:
        return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-")
                for h in re.findall(r"^#+ (.*)$", PAGES[page], re.M)}

    broken = []
    for page, text in PAGES.items():
        for link, anchor in re.findall(r"\]\(([^)#\s]*)(?:#([^)\s]*))?\)", text):
            if "://" in link:
                continue
            path = (REPO / page).parent.joinpath(link or page.rsplit("/", 1)[-1]).resolve()
            target = path.relative_to(REPO.resolve()).as_posix() if path.is_relative_to(REPO.resolve()) else None
            if not path.exists() or (anchor and (target not in PAGES or anchor not in anchors(target))):
                broken.append(f"{page}: {link}#{anchor}" if anchor else f"{page}: {link}")
    assert not broken, f"links to missing files or headings: {broken}"
