"""Chaos at every instant of a job: a stop or a crash at any moment hands the job back, never fails it or loses it.

The seeded trials (``tests.chaos``): ``CTP_CHAOS_TRIALS`` of them (20 by default, five of each fault, for the
suite's time; the 200 of docs/service.md are ``benchmarks/soak.py --chaos 200``), seed ``CTP_CHAOS_SEED``, each a
fault at an instant drawn over a job's life as measured first (``CTP_CHAOS_SPAN_S`` fixes that span;
``CTP_CHAOS_ONLY`` runs one trial: a failure prints all three).
Before them, the Ctrl-C that once failed a job while its meshes loaded, replayed as it happened, and the API killed
at the two seams of a submit (a fault point, ``service.faults``). All on one deployment, in this order.
"""

from __future__ import annotations

import json
import os
import signal
import time
import uuid
from datetime import datetime
from pathlib import Path

import httpx
import pytest

from service.faults import VARIABLE
from tests.chaos import Deployment
from tests.conftest import wait_for
from tests.test_service_serve import _cmdline, children

TRIALS = int(os.environ.get("CTP_CHAOS_TRIALS", "20"))
SEED = int(os.environ.get("CTP_CHAOS_SEED", "51"))
ONLY = os.environ.get("CTP_CHAOS_ONLY")
SPAN_S = os.environ.get("CTP_CHAOS_SPAN_S")


@pytest.fixture(scope="module")
def deployment(tmp_path_factory):
    root = tmp_path_factory.mktemp("chaos")
    try:
        deployment = Deployment(root)
    except (OSError, RuntimeError) as exc:
        pytest.skip(f"the processes of the chaos deployment could not be started: {exc}")
    yield deployment
    deployment.stop()


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs Linux /proc to see the worker's loading process start")
def test_ctrl_c_while_meshes_load_hands_the_job_back(deployment):
    """The regression: Ctrl-C (SIGINT to the process group of the API and the workers) while a job's meshes load,
    about 0.35 s after it started: a worker's first job, whose loading process is starting then, the instant that
    once failed the job ``loader_unavailable``. The signal is sent as that process appears, so the instant falls in
    its start however fast the machine. The job is handed back and succeeds after the restart on its first counted
    attempt."""
    if deployment.submitted:  # a job ran: its worker's loading process is up, so start workers that have none
        deployment.restart_workers()
    job_id = deployment.submit(uuid.uuid4().hex).json()["id"]
    worker_pid = wait_for(lambda: deployment.worker_pid(job_id), 60, "the job to start", interval_s=0.01)
    wait_for(lambda: any("ctp_core.io.loader" in _cmdline(p) for p in children(worker_pid)), 30,
             "the job's loading process to start", interval_s=0.002)
    after_s = time.time() - datetime.fromisoformat(deployment.job(job_id)["started_at"]).timestamp()
    seen = deployment.job(job_id)
    deployment.fault("sigint", job_id)
    assert seen["progress"]["stage"]["name"] == "loading", f"the signal missed the loading: {seen['progress']}"
    job = deployment.wait_end(job_id)
    assert (job["status"], job["attempts"], job["error"]) == ("succeeded", 1, None), (after_s, job)
    logs = "".join(path.read_text(errors="replace") for path in deployment.root.glob("worker-*.log"))
    assert '"msg": "job queued again"' in logs and "loader_unavailable" not in logs


def test_an_api_killed_at_both_seams_of_a_submit_makes_one_job(deployment):
    """One request, its API killed (SIGKILL, at a fault point) twice: after storing the uploads but before the
    record, then, sent again with its Idempotency-Key once the dead request's claim lapsed, after queueing the job
    but before answering. Sent a third time it is answered 200 with the job queued before the second crash: exactly
    one job, and it runs."""
    before = len(deployment.records())
    key = uuid.uuid4().hex
    deployment.restart_api(**{VARIABLE: "submit.stored"})
    for point in ("submit.stored", "submit.queued"):
        with pytest.raises(httpx.TransportError):
            deployment.submit(key, retry=False)
        assert deployment.api.wait(timeout=30) == -signal.SIGKILL, point
        deployment.start_api(**({VARIABLE: "submit.queued"} if point == "submit.stored" else {}))
    again = deployment.submit(key)
    assert again.status_code == 200, again.text  # the replay of the job queued before the crash
    job = deployment.wait_end(again.json()["id"])
    assert (job["status"], job["attempts"]) == ("succeeded", 1), job
    assert len(deployment.records()) == before + 1


def test_a_fault_at_any_instant_of_a_job_loses_and_fails_no_job(deployment):
    """Each trial: one job, one fault at a drawn instant (SIGINT to the group, SIGKILL of the worker, of redis-server,
    of the API; some trials cancel too), what it killed restarted; the job succeeds (or is canceled as asked) with
    whole results and one delivery per webhook event; then one record per job and no answer 500."""
    life_s = deployment.calibrate()
    span_s = float(SPAN_S) if SPAN_S else round(1.25 * life_s, 2)
    started = time.monotonic()
    for index in [int(ONLY)] if ONLY is not None else range(TRIALS):
        deployment.trial(SEED, index, span_s)
    figures = {**deployment.check_all(), "seed": SEED, "span_s": span_s, "calibration_s": round(life_s, 2),
               "wall_s": round(time.monotonic() - started, 1)}
    print(json.dumps(figures))
    assert figures["jobs"].get("succeeded", 0) + figures["jobs"].get("canceled", 0) == len(deployment.trials)
