"""Soak of the embedded service: hostile uploads mixed with valid jobs while workers are killed.

Runs ``ctp serve --workers 2`` (embedded Redis, supervised workers) on 127.0.0.1 with the tiny random
model, then for ``--minutes`` (or ``--requests``) sends, from ``--clients`` threads, a mix of valid jobs
(the ``test`` preset) and hostile uploads (the refusals the tests pin down: a deep node chain, a wide
scene graph cut at the wall-time limit, bad ``data:`` buffers, symlinks and bombs in zips, NaN vertices,
too many faces, control characters, 65-bit integers, deep JSON), and with ``--extreme-share`` valid uploads
in extreme units and size ratios (a sphere of radius 5,000 beside a 0.3 m box, either way round; micrometre and
kilometre pairs; a needle; a 1e-4 ratio). Every few seconds (uniform in ``--kill-every``; ``0 0``: never) it
SIGKILLs one worker at random, and (``--redis-kill-every``) the embedded redis-server; the supervisor brings
either back.

It reports, and checks: every valid job ends ``succeeded`` and none is lost (``jobs_lost``: stuck, or failed
``worker_lost``; a job whose worker is killed is run again once, a Redis outage is waited out; the check allows only
a job whose worker was killed on both its attempts, the retry bound, and reports it); every extreme job
ends ``succeeded`` or ``failed`` with a documented code (``job_too_large``); no worker died but those killed (a
worker process that disappears otherwise is a death); every hostile request is a 4xx; no 5xx but 503s while a
dependency is down; no raw traceback in serve's log; the API process's peak RSS (the bound is ``--rss-mb``); the
p99 latency of ``GET /jobs/{id}`` (the bound is ``--status-p99-ms``). A measurement, not a test: it prints JSON
and exits 1 when a check fails.

    python benchmarks/soak.py --minutes 3
    python benchmarks/soak.py --minutes 3 --redis-kill-every 20 40
    python benchmarks/soak.py --minutes 4 --kill-every 0 0 --extreme-share 0.5 --valid-share 0.5

``--chaos N`` runs, instead, N seeded chaos trials (``tests.chaos``, the harness of ``tests/test_chaos.py``): the
service as separate processes, one job at a time, each hit by one fault at an instant drawn over its life (SIGINT to
the process group, SIGKILL of the worker running it, of redis-server, of the API; some also canceled), what was killed
restarted, and every promise checked (the job ends succeeded or canceled as asked, whole results, one record per job,
one delivery per webhook event, no 500). A broken promise is recorded with its trial, fault, instant and seed, and the
trials go on; it prints the figures (JSON) and exits 1 when any was broken:

    python benchmarks/soak.py --chaos 200 --seed 51
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import numpy as np
import trimesh

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from ctp.cmd_serve import stop_processes  # noqa: E402
from service.embedded import free_port, servers_using  # noqa: E402
from tests.test_loader import wide_glb  # noqa: E402
from tests.test_service import (  # noqa: E402
    deep_chain_glb,
    gltf_with_uri,
    grid_mesh,
    obj_zip_bomb,
    obj_zip_with_symlink,
    ply,
)
from tests.test_service_serve import alive, children  # noqa: E402

OPTIONS = {"preset": "test", "model": "random:tiny"}
TERMINAL = ("succeeded", "failed", "canceled")


def _box_and_ball() -> tuple[bytes, bytes]:
    """The valid pair (GLB bytes): a unit box and a ball to put on it."""
    return (trimesh.creation.box().export(file_type="glb"),
            trimesh.creation.icosphere(subdivisions=2, radius=0.3).export(file_type="glb"))


def _sphere(radius: float) -> bytes:
    """A binary PLY sphere, as the issue's report uploaded it."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return ply(mesh.vertices, mesh.faces)


def _box(side: float) -> bytes:
    return trimesh.creation.box(extents=[side] * 3).export(file_type="glb")


def _extreme() -> list[tuple[str, dict]]:
    """Valid uploads in extreme units or size ratios: (name, files). The first is the issue's worker killer."""
    needle = trimesh.creation.box(extents=[0.001, 1.0, 0.001]).export(file_type="glb")
    return [
        ("r5000 sphere <- 0.3 m box", {"target": ("big.ply", _sphere(5000.0)), "source": ("box.glb", _box(0.3))}),
        ("0.3 m box <- r5000 sphere", {"target": ("box.glb", _box(0.3)), "source": ("big.ply", _sphere(5000.0))}),
        ("micrometre pair", {"target": ("a.ply", _sphere(1.5e-7)), "source": ("b.glb", _box(3e-7))}),
        ("kilometre pair", {"target": ("a.ply", _sphere(1.5e5)), "source": ("b.glb", _box(3e5))}),
        ("ratio 1e-4", {"target": ("a.ply", _sphere(1500.0)), "source": ("b.glb", _box(0.3))}),
        ("needle <- box", {"target": ("needle.glb", needle), "source": ("b.glb", _box(0.3))}),
    ]


def _hostile() -> list[tuple[str, dict, dict]]:
    """(name, files, form fields) of uploads the API must refuse with a 4xx."""
    box, ball = _box_and_ball()
    ok = json.dumps(OPTIONS)
    nan = ply(np.array([[0, 0, 0], [float("nan"), 1, 0], [0, 1, 1]]), [[0, 1, 2]])

    def upload(target=("box.glb", box), source=("ball.glb", ball), prompt="a ball on a box", options=ok, **extra):
        return {"target": target, "source": source}, {"prompt": prompt, "options": options, **extra}

    cases = {
        "deep node chain": upload(target=("deep.glb", deep_chain_glb(5000))),
        "wide scene graph": upload(source=("wide.glb", wide_glb(60_000))),
        "data uri byteLength": upload(target=("t.gltf", gltf_with_uri("data:application/octet-stream;base64,AAAA"))),
        "external uri": upload(target=("t.gltf", gltf_with_uri("http://169.254.169.254/latest"))),
        "zip symlink": upload(source=("s.zip", obj_zip_with_symlink())),
        "zip bomb": upload(source=("s.zip", obj_zip_bomb(16 * 2**20))),
        "nan vertices": upload(target=("t.ply", nan)),
        "2M faces": upload(source=("s.ply", ply(*grid_mesh(1001)))),
        "random bytes": upload(target=("t.glb", os.urandom(200_000))),
        "NUL prompt": upload(prompt="a ball\x00on a box"),
        "ESC name": upload(source_name="ball\x1b[2J"),
        "65-bit seed": upload(options=json.dumps({**OPTIONS, "seed": 2**64 + 1})),
        "deep json": upload(options="[" * 50_000 + "]" * 50_000),
        "NaN option": upload(options='{"contact_ratio": NaN}'),
        "unknown option": upload(options=json.dumps({**OPTIONS, "temperature": 2})),
    }
    return [(name, files, data) for name, (files, data) in cases.items()]


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _children(pid: int) -> list[int]:
    return [p for p in children(pid) if alive(p)]


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _children_running(pid: int, needle: str) -> list[int]:
    """Live children of ``pid`` whose command line holds ``needle`` (" worker", "ctp_core.io.loader")."""
    return [p for p in _children(pid) if needle in _cmdline(p)]


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    if args.chaos:
        return _chaos(args)
    rng = random.Random(args.seed)

    tmp = tempfile.TemporaryDirectory()
    env = {**os.environ, "XDG_CACHE_HOME": tmp.name, "CTP_MODEL": "random:tiny", "CTP_LOG_LEVEL": "WARNING",
           "CTP_MAX_ACTIVE_JOBS": "100000", "CTP_THREADS": "1", "OMP_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE",
           "CTP_HEARTBEAT_S": "0.5", "CTP_LEASE_S": "5", "CTP_LOAD_TIMEOUT_S": "5", "CTP_MAX_NODES": "1000000"}
    env.pop("REDIS_URL", None)
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    log = open(Path(tmp.name) / "serve.log", "wb")  # noqa: SIM115 - closed below
    serve = subprocess.Popen([sys.executable, "-m", "ctp", "serve", "--port", str(port), "--workers", "2"],
                             env=env, cwd=REPO, stdout=log, stderr=subprocess.STDOUT)
    soak = _Soak(args, serve, url, Path(tmp.name) / "ctp" / "redis")
    try:
        soak.wait_ready()
        soak.run(rng)
    finally:
        soak.stop.set()
        stop_processes([serve], grace_s=60)
        log.close()
    # Raw tracebacks (not inside a JSON log line): what the service must never print.
    tracebacks = (Path(tmp.name) / "serve.log").read_text(errors="replace").count("\nTraceback (most recent call")
    figures = _figures(soak, tracebacks)
    print(json.dumps(figures, indent=2))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))
    tmp.cleanup()
    return 0 if figures["ok"] else 1


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=3.0, help="how long to send requests")
    parser.add_argument("--requests", type=int, default=5000, help="stop sending after this many")
    parser.add_argument("--clients", type=int, default=3, help="threads sending requests")
    parser.add_argument("--valid-share", type=float, default=0.3, help="share of requests that are valid jobs")
    parser.add_argument("--extreme-share", type=float, default=0.0,
                        help="share of the valid jobs whose uploads are in extreme units or size ratios")
    parser.add_argument("--kill-every", type=float, nargs=2, default=(10.0, 25.0), metavar=("MIN_S", "MAX_S"),
                        help="seconds between worker kills, uniform; 0 0: no kills")
    parser.add_argument("--redis-kill-every", type=float, nargs=2, default=(0.0, 0.0), metavar=("MIN_S", "MAX_S"),
                        help="seconds between SIGKILLs of the embedded redis-server, uniform; 0 0: none")
    parser.add_argument("--rss-mb", type=float, default=600.0, help="bound on the API process's RSS")
    parser.add_argument("--status-p99-ms", type=float, default=250.0, help="bound on GET /jobs/{id}'s p99 latency")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    parser.add_argument("--chaos", type=int, default=0, metavar="N", help="run N seeded chaos trials instead")
    parser.add_argument("--span-s", type=float, default=None,
                        help="--chaos: draw the instants over this many seconds (default: 1.25 x a job's life)")
    return parser.parse_args(argv)


def _chaos(args: argparse.Namespace) -> int:
    """``--chaos N``: the trials, every one run even after a broken promise; the figures printed (and ``--json``)."""
    from tests.chaos import ChaosFailure, Deployment

    started = time.monotonic()
    broken: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        deployment = Deployment(Path(tmp))
        try:
            life_s = deployment.calibrate()
            span_s = args.span_s or round(1.25 * life_s, 2)
            for index in range(args.chaos):
                try:
                    deployment.trial(args.seed, index, span_s)
                except ChaosFailure as exc:
                    broken.append(str(exc))
            figures = deployment.figures()
        finally:
            deployment.stop()
    ledger = figures["ledger"]
    broken += [f"{what}: {ledger[key]}" for key, what in (("lost", "records lost"), ("listed_twice", "records listed "
               "twice"), ("of_no_submit", "records of no submit")) if ledger[key]]
    if figures["statuses"].get("500"):
        broken.append(f"{figures['statuses']['500']} answers 500")
    figures.update(seed=args.seed, span_s=span_s, calibration_s=round(life_s, 2),
                   wall_s=round(time.monotonic() - started, 1), broken=broken, ok=not broken)
    print(json.dumps(figures, indent=2))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))
    return 0 if figures["ok"] else 1


class _Soak:
    """One soak of a running ``ctp serve``: the threads that send requests, kill workers and Redis, and watch
    workers and memory, and what they record (under ``lock``): the answers, the jobs and how they ended, the kills,
    the deaths, the RSS and status-latency samples."""

    def __init__(self, args: argparse.Namespace, serve: subprocess.Popen, url: str, redis_dir: Path):
        self.args, self.serve, self.url, self.redis_dir = args, serve, url, redis_dir
        self.hostile = _hostile()
        self.counts: collections.Counter = collections.Counter()
        self.statuses: collections.Counter = collections.Counter()
        self.valid: list[str] = []
        self.kind: dict[str, str] = {}  # job id -> "valid" or the extreme pair's name
        self.latencies: list[float] = []
        self.kills: list[float] = []
        self.redis_kills: list[float] = []
        self.deaths: list[int] = []  # worker pids that vanished without being killed here
        self.rss: list[float] = []
        self.loader_rss: list[float] = [0.0]
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.sent = 0
        self.box, self.ball = _box_and_ball()
        self.extreme = _extreme()
        self.killed: set[int] = set()
        self.ended: dict[str, dict] = {}
        self.sending_s = 0.0

    def wait_ready(self) -> None:
        """Until serve reports its two workers (at most 3 minutes)."""
        with httpx.Client(base_url=self.url, timeout=120) as client:
            deadline = time.monotonic() + 180
            while True:
                try:
                    if client.get("/readyz").json().get("workers", 0) >= 2:
                        break
                except httpx.TransportError:
                    pass
                if time.monotonic() > deadline or self.serve.poll() is not None:
                    raise RuntimeError("ctp serve did not become ready")
                time.sleep(0.5)

    def run(self, rng: random.Random) -> None:
        """Send from ``--clients`` threads for ``--minutes`` (or ``--requests``) with the killers and watchers
        running, polling the valid jobs; then wait up to 3 minutes for those still running."""
        args = self.args
        started = time.monotonic()
        threads = [threading.Thread(target=self.send, args=(args.seed + i,)) for i in range(args.clients)]
        workers = functools.partial(_children_running, self.serve.pid, " worker")
        servers = functools.partial(servers_using, self.redis_dir)  # the redis-server itself, not its keeper
        helpers = [threading.Thread(target=self.kill_loop, args=(args.kill_every, workers, self.kills, rng.random()),
                                    daemon=True),
                   threading.Thread(target=self.kill_loop, args=(args.redis_kill_every, servers, self.redis_kills,
                                                                 rng.random()), daemon=True),
                   *(threading.Thread(target=f, daemon=True) for f in (self.watch_rss, self.watch_workers))]
        for t in [*threads, *helpers]:
            t.start()
        with httpx.Client(base_url=self.url, timeout=30) as client:
            while any(t.is_alive() for t in threads):
                if time.monotonic() - started > 60 * args.minutes:
                    self.stop.set()
                self.poll(client)
                time.sleep(1.0)
            self.sending_s = time.monotonic() - started
            self.stop.set()
            drain = time.monotonic() + 180
            while len(self.ended) < len(self.valid) and time.monotonic() < drain:
                self.poll(client)
                time.sleep(1.0)

    def request(self, local: random.Random, in_flight: int) -> tuple[str, dict, dict]:
        """The next request (name, files, form): a valid job (``--valid-share``, while fewer than 6 run; an
        extreme pair for ``--extreme-share`` of them) or a hostile upload."""
        if local.random() < self.args.valid_share and in_flight < 6:
            name, files, data = "valid", {"target": ("box.glb", self.box), "source": ("ball.glb", self.ball)}, {
                "prompt": "a ball on top of a box", "options": json.dumps(OPTIONS)}
            if local.random() < self.args.extreme_share:
                label, files = local.choice(self.extreme)
                name = f"extreme {label}"
            return name, files, data
        return local.choice(self.hostile)

    def send(self, seed: int) -> None:
        """A client: requests until stopped or ``--requests`` are sent; each answer counted, each job accepted
        kept."""
        local = random.Random(seed)
        with httpx.Client(base_url=self.url, timeout=120) as client:
            while not self.stop.is_set():
                with self.lock:
                    if self.sent >= self.args.requests:
                        return
                    self.sent += 1
                    in_flight = len(self.valid) - self.statuses["ended"]
                name, files, data = self.request(local, in_flight)
                try:
                    answer = client.post("/align", files=files, data=data)
                except httpx.TransportError as exc:
                    with self.lock:
                        self.counts[f"transport error {type(exc).__name__}"] += 1
                    continue
                with self.lock:
                    self.counts[f"{name}: {answer.status_code}"] += 1
                    if name.startswith(("valid", "extreme")) and answer.status_code == 202:
                        self.valid.append(answer.json()["id"])
                        self.kind[self.valid[-1]] = name

    def kill_loop(self, every: tuple[float, float], victims: Callable[[], list[int]], done: list[float],
                  seed: float) -> None:
        """SIGKILL one of ``victims()`` every ``every`` seconds (uniform)."""
        local = random.Random(seed)
        if max(every) <= 0:
            return
        while not self.stop.wait(local.uniform(*every)):
            pids = victims()
            if pids:
                victim = local.choice(pids)
                self.killed.add(victim)
                os.kill(victim, signal.SIGKILL)
                done.append(time.monotonic())

    def watch_workers(self) -> None:
        """A worker pid that disappears without a kill from here died (memory, a crash)."""
        known = set(_children_running(self.serve.pid, " worker"))
        while not self.stop.wait(0.5):
            now = set(_children_running(self.serve.pid, " worker"))
            self.deaths.extend(pid for pid in known - now if pid not in self.killed)
            known = now

    def watch_rss(self) -> None:
        while not self.stop.wait(0.5):
            self.rss.append(_rss_mb(self.serve.pid))
            self.loader_rss.extend(_rss_mb(p) for p in _children_running(self.serve.pid, "ctp_core.io.loader"))

    def poll(self, client: httpx.Client) -> None:
        """The status of every valid job not ended yet, its latency sampled; the ended kept."""
        for job_id in [j for j in list(self.valid) if j not in self.ended]:
            try:
                asked = time.perf_counter()
                job = client.get(f"/jobs/{job_id}").json()
                self.latencies.append(time.perf_counter() - asked)
            except (httpx.TransportError, ValueError):
                continue
            if job.get("status") in TERMINAL:
                self.ended[job_id] = job
                with self.lock:
                    self.statuses["ended"] += 1


def _outcome(job: dict) -> str:
    return job["status"] if job["status"] != "failed" else f"failed {job['error']['code']}"


def _figures(soak: _Soak, tracebacks: int) -> dict:
    """What the soak reports, and ``ok``: whether every check passed (see the module docstring)."""
    args, counts, ended, kind, latencies, rss = soak.args, soak.counts, soak.ended, soak.kind, soak.latencies, soak.rss
    valid = soak.valid
    outcomes = collections.Counter(_outcome(j) for i, j in ended.items() if kind[i] == "valid")
    extreme_outcomes = collections.Counter(f"{kind[i]}: {_outcome(j)}" for i, j in ended.items()
                                           if kind[i] != "valid")
    hostile_answers = {k: v for k, v in counts.items() if not k.startswith(("valid", "extreme"))}
    figures = {
        "sending_s": round(soak.sending_s, 1), "requests": soak.sent, "worker_kills": len(soak.kills),
        "redis_kills": len(soak.redis_kills), "serve_log_raw_tracebacks": tracebacks,
        "valid_accepted": len(valid), "valid_outcomes": dict(outcomes), "valid_stuck": len(valid) - len(ended),
        "extreme_outcomes": dict(sorted(extreme_outcomes.items())), "worker_deaths": len(soak.deaths),
        "status_latency_ms": {"requests": len(latencies),
                              "p50": round(1000 * float(np.percentile(latencies, 50)), 1) if latencies else None,
                              "p99": round(1000 * float(np.percentile(latencies, 99)), 1) if latencies else None,
                              "bound_p99": args.status_p99_ms},
        "hostile_4xx": sum(v for k, v in hostile_answers.items() if k.rsplit(": ", 1)[-1].startswith("4")),
        "hostile_other": {k: v for k, v in hostile_answers.items() if not k.rsplit(": ", 1)[-1].startswith("4")},
        "answers": dict(sorted(counts.items())),
        "status_500": sum(v for k, v in counts.items() if k.endswith(": 500")),
        "api_rss_mb": {"start": round(rss[0], 1) if rss else None, "peak": round(max(rss, default=0), 1),
                       "end": round(rss[-1], 1) if rss else None, "bound": args.rss_mb},
        "loader_process_rss_peak_mb": round(max(soak.loader_rss), 1),
    }
    figures["jobs_lost"] = figures["valid_stuck"] + outcomes.get("failed worker_lost", 0) + sum(
        v for k, v in extreme_outcomes.items() if k.endswith("failed worker_lost"))
    figures["jobs_run_again"] = sum(1 for j in ended.values() if j.get("attempts", 1) > 1)
    lost_jobs = [j for j in ended.values() if j["status"] == "failed" and j["error"]["code"] == "worker_lost"]
    figures["lost_jobs"] = [{"attempts": j["attempts"], "message": j["error"]["message"]} for j in lost_jobs]
    # A job whose worker is killed on both its attempts is lost by design (the bound that keeps a job that kills
    # workers from taking them all down); any other loss is the service's failure.
    figures["jobs_lost_unbounded"] = figures["jobs_lost"] - sum(1 for j in lost_jobs if j["attempts"] >= 2)
    p99 = figures["status_latency_ms"]["p99"]
    figures["ok"] = (figures["jobs_lost_unbounded"] == 0 and figures["status_500"] == 0 and not figures["hostile_other"]
                     and not tracebacks
                     and set(outcomes) <= {"succeeded", "failed worker_lost"}
                     and all(k.endswith(("succeeded", "failed job_too_large")) for k in extreme_outcomes)
                     and not soak.deaths and max(rss, default=0) <= args.rss_mb
                     and (p99 is None or p99 <= args.status_p99_ms))
    return figures


if __name__ == "__main__":
    sys.exit(main())
