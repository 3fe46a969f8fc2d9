"""The README's commands, run as they stand in README.md (read from it, never a copy): the Quick start's
``ctp align`` on the generated sample pair, the curl walk-through and the Python client against a real
``ctp serve``, and the command-line synopsis, which must be what the parsers accept.

Two things are supplied around the text, because a test cannot do them itself: ``make install`` (these
tests already run in the venv it built; the line is checked to be that call and nothing else) and the
service the README starts in another terminal with ``CTP_MODEL=random:tiny make serve``, which here is
``ctp serve`` with that setting on a free port (the only change to the commands: ``127.0.0.1:8000`` becomes
that port, so parallel runs cannot collide).
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
from ctp_core.samples import get_sample
from service.embedded import free_port
from tests.conftest import REPO, service_env, wait_for

README = (REPO / "README.md").read_text()


def block(marker: str) -> str:
    """The first fenced code block after ``<!-- readme-test:MARKER -->``."""
    found = re.search(rf"<!-- readme-test:{marker} -->\s*```\w*\n(.*?)```", README, re.S)
    assert found, f"README.md has no code block after <!-- readme-test:{marker} -->"
    return found.group(1)


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
    assert set(scene.geometry) == {"target", "source"}
    report = json.loads((tmp_path / "try" / "report.json").read_text())
    assert (report["hparams"]["target_name"], report["hparams"]["source_name"]) == ("table", "cup")
    assert (tmp_path / "try" / "preview.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.skipif(shutil.which("curl") is None, reason="the walk-through needs curl, which is not installed")
def test_service_walk_through_and_client_run_as_written(tmp_path):
    get_sample("cup-on-table").write(tmp_path / "try")  # what the Quick start's `ctp example --dir try` wrote
    port = free_port()
    env = {**service_env("unused", "ctp"), "XDG_CACHE_HOME": str(tmp_path / "cache")}
    del env["REDIS_URL"]
    assert env["CTP_MODEL"] == "random:tiny"  # as in `CTP_MODEL=random:tiny make serve`
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
        assert "event: end" in run.stdout and '"status":"succeeded"' in run.stdout
        assert '"code":"job_finished"' in run.stdout  # the last line: cancel of the ended job
        served = trimesh.load(tmp_path / "try" / "served.glb", force="scene")
        assert set(served.geometry) == {"target", "source"}
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
    found = re.search(r"<!-- synopsis:start.*?-->\s*```\n(.*?)```\s*<!-- synopsis:end -->", README, re.S)
    assert found, "README.md has no synopsis block"
    assert found.group(1).rstrip() == synopsis(), (
        'the README synopsis is stale: paste the output of python -c "from ctp.cli import synopsis; print(synopsis())"')


def test_priors_needs_no_prompt(capsys):
    assert main(["priors", "--target", "table", "--source", "cup"]) == 0
    assert json.loads(capsys.readouterr().out)["penetration"] is False


def test_every_setting_is_in_the_settings_table_once():
    from service.settings import Settings

    rows = re.findall(r"^\| `((?:CTP_)?[A-Z_]+)` \|", README, re.M)
    names = ["REDIS_URL" if n == "redis_url" else f"CTP_{n.upper()}" for n in Settings.model_fields]
    assert sorted(rows) == sorted(names), "README's settings table and service/settings.py disagree"
