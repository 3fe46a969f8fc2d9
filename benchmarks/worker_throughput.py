"""One worker's throughput and memory on a fixed job mix: jobs per minute (per kind and overall), each job's
seconds and CPU seconds, and the resident memory the worker holds idle, at its peak during the mix and after it.
A measurement, not a test: it prints numbers.

Runs, as ``service_load.py`` does, a private redis-server, the API under uvicorn and one ``ctp worker`` (the tiny
random model, one torch thread), then submits the whole mix at once over HTTP and waits for it. The mix is made
of the built-in examples (``ctp_core.io.examples``: a cup on a table, an apple in a bowl, taken in turn), seeds
0, 1, ...:

- ``--geometry N`` pairs without a guide (``lambda_clip`` 0: the geometry and the prompt's relation place them);
- ``--guided M`` pairs guided by ``random:tiny`` (the preset's guide settings, no weights downloaded);
- ``--scenes S`` assemblies (``POST /assemble``) of five objects without a guide: the table setting's (a plate
  on the table, a cup on the plate) and a bowl on the table with an apple in it.

The worker runs jobs in its own process (``worker.main``: rq's ``SimpleWorker``, no fork per job) and loads
meshes in a child (``ctp_core.io.loader``); both are read from /proc every ``--sample-s``: CPU seconds and
``VmRSS``, and ``VmHWM`` (the kernel's high-water mark) at the end. A job's CPU seconds are the worker's and its
children's between the job's ``started_at`` and ``finished_at`` (interpolated between samples). Jobs per minute:
overall, the jobs over the wall time from the first submit to the last finish; per kind, the kind's jobs over
the sum of their run seconds (the rate of a worker given only that kind).

    PYTHONPATH=$PWD .venv/bin/python benchmarks/worker_throughput.py          # 20 + 10 + 2 jobs, default preset
    PYTHONPATH=$PWD .venv/bin/python benchmarks/worker_throughput.py --geometry 4 --guided 2 --scenes 1 \\
        --preset fast --json out.json
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from datetime import datetime
from pathlib import Path

import httpx
from service_load import REPO, running_service, until_ready  # a sibling script (benchmarks/ is on sys.path)

sys.path.insert(0, str(REPO))

from ctp_core.io.examples import EXAMPLES, get_example, write_table_setting  # noqa: E402
from tests.test_service_serve import descendants  # noqa: E402

TERMINAL = ("succeeded", "failed", "canceled")
TICK_S = os.sysconf("SC_CLK_TCK")
# POST /assemble's plan on the table (the base): five objects in all
SCENE_STEPS = [{"file": "plate.glb", "prompt": "a plate on the table"},
               {"file": "cup.glb", "prompt": "a cup on the plate", "on": "plate"},
               {"file": "bowl.glb", "prompt": "a bowl on the table", "on": "table"},
               {"file": "apple.glb", "prompt": "an apple in the bowl", "on": "bowl"}]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--geometry", type=int, default=20, help="pairs without a guide")
    parser.add_argument("--guided", type=int, default=10, help="pairs guided by random:tiny")
    parser.add_argument("--scenes", type=int, default=2, help="five-object assemblies without a guide")
    parser.add_argument("--preset", default="default", help="every job's preset")
    parser.add_argument("--sample-s", type=float, default=0.2, help="seconds between /proc samples of the worker")
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    args = parser.parse_args(argv)

    total = args.geometry + args.guided + args.scenes
    with running_service(1, max_active_jobs=max(total, 1)) as (url, (worker,)):
        figures = asyncio.run(_measure(url, worker.pid, args))
    print(json.dumps(figures, indent=2))
    print(table(figures))
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2))
    return 0 if figures["overall"]["succeeded"] == total else 1


def mix(geometry: int, guided: int, scenes: int, preset: str, folder: Path) -> list[tuple[str, str, str, dict, dict]]:
    """The fixed jobs, in submitting order: (kind, case, route, files, form fields)."""
    pairs = list(EXAMPLES.values())
    jobs = []
    for kind, count, options in (("geometry", geometry, {"lambda_clip": 0}),
                                 ("guided", guided, {"model": "random:tiny"})):
        for i in range(count):
            example = pairs[i % len(pairs)]
            files = example.files()
            upload = {"target": (example.target_file, files[example.target_file]),
                      "source": (example.source_file, files[example.source_file])}
            form = {"prompt": example.prompt, "options": json.dumps({"preset": preset, "seed": i, **options})}
            jobs.append((kind, example.name, "/align", upload, form))
    if scenes:
        write_table_setting(folder)
        get_example("apple-in-bowl").write(folder)
        files = [("base", ("table.glb", (folder / "table.glb").read_bytes()))]
        files += [("source", (s["file"], (folder / s["file"]).read_bytes())) for s in SCENE_STEPS]
    for i in range(scenes):
        jobs.append(("scene", "table setting, bowl, apple", "/assemble", files,
                     {"plan": json.dumps(SCENE_STEPS),
                      "options": json.dumps({"preset": preset, "seed": i, "lambda_clip": 0})}))
    return jobs


class Sampler(threading.Thread):
    """Samples a process and its descendants from /proc every ``period_s``: (time, CPU seconds, the process's
    ``VmRSS`` MB, its descendants' summed ``VmRSS`` MB); ``VmHWM`` is read once, at the end."""

    def __init__(self, pid: int, period_s: float):
        super().__init__(name="sampler", daemon=True)
        self.pid, self.period_s = pid, period_s
        self.samples: list[tuple[float, float, float, float]] = []
        self.children: set[int] = set()  # every descendant seen
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.is_set():
            self.sample()
            self._halt.wait(self.period_s)

    def stop(self) -> None:
        self._halt.set()
        self.join()

    def sample(self) -> None:
        now = descendants(self.pid)
        self.children.update(now)
        self.samples.append((time.time(), sum(_cpu_s(p) for p in [self.pid, *now]), _status_mb(self.pid, "VmRSS"),
                             sum((_status_mb(p, "VmRSS") for p in now), 0.0)))

    def cpu_at(self, when: float) -> float:
        """Cumulative CPU seconds at ``when`` (epoch), interpolated between the samples around it."""
        times = [s[0] for s in self.samples]
        i = min(max(bisect.bisect_left(times, when), 1), len(times) - 1)
        (t0, c0, *_), (t1, c1, *_) = self.samples[i - 1], self.samples[i]
        return c0 + (c1 - c0) * min(max((when - t0) / max(t1 - t0, 1e-9), 0.0), 1.0)

    def between(self, start: float, end: float) -> list[tuple[float, float, float, float]]:
        """The samples taken from ``start`` to ``end`` (epoch)."""
        return [s for s in self.samples if start <= s[0] <= end]


async def _measure(url: str, worker: int, args: argparse.Namespace) -> dict:
    async with httpx.AsyncClient(base_url=url, timeout=120) as client:
        await until_ready(client, 1)
        sampler = Sampler(worker, args.sample_s)
        sampler.start()
        await asyncio.sleep(5)  # idle: the model preloaded, the heartbeat running
        idle = sampler.samples[-1]
        idle_cpu_rate = (idle[1] - sampler.samples[0][1]) / max(idle[0] - sampler.samples[0][0], 1e-9)
        with tempfile.TemporaryDirectory() as tmp:
            jobs = mix(args.geometry, args.guided, args.scenes, args.preset, Path(tmp))
        first_submit = time.time()
        ids = []
        for kind, case, route, files, data in jobs:
            answer = await client.post(route, files=files, data=data)
            if answer.is_error:
                raise RuntimeError(f"POST {route} refused the mix's {kind} job: {answer.status_code} {answer.text}")
            ids.append(((kind, case), answer.json()["id"]))
        records = []
        for label, job_id in ids:  # one worker takes them in order: wait on the oldest unfinished only
            while (job := (await client.get(f"/jobs/{job_id}")).json())["status"] not in TERMINAL:
                await asyncio.sleep(0.5)
            records.append((label, job))
        await asyncio.sleep(5)  # after: the last job's memory released, if it is
        after = sampler.samples[-1]
        sampler.stop()
        hwm = {"worker": _status_mb(worker, "VmHWM"),
               "children": {str(p): _status_mb(p, "VmHWM") for p in sorted(sampler.children)}}
    return _figures(records, sampler, first_submit, idle, idle_cpu_rate, after, hwm, args)


def _figures(records: list[tuple[tuple[str, str], dict]], sampler: Sampler, first_submit: float, idle: tuple,
             idle_cpu_rate: float, after: tuple, hwm: dict, args: argparse.Namespace) -> dict:
    per_job = []
    for (kind, case), job in records:
        created, started, finished = (_epoch(job[k]) for k in ("created_at", "started_at", "finished_at"))
        run_s = None if started is None or finished is None else finished - started
        per_job.append({
            "kind": kind, "case": case, "status": job["status"], "guide": job.get("guide"),
            "error": (job.get("error") or {}).get("code"),
            "queued_s": None if started is None else round(started - created, 2),
            "run_s": None if run_s is None else round(run_s, 2),
            "cpu_s": None if run_s is None else round(sampler.cpu_at(finished) - sampler.cpu_at(started), 2)})
    last_finish = max(_epoch(job["finished_at"]) or first_submit for _, job in records) if records else first_submit
    wall = last_finish - first_submit
    during = sampler.between(first_submit, last_finish) or [idle]
    kinds = {}
    for kind in dict.fromkeys(j["kind"] for j in per_job):
        mine = [j for j in per_job if j["kind"] == kind and j["run_s"] is not None]
        run = sum(j["run_s"] for j in mine)
        kinds[kind] = {"jobs": sum(j["kind"] == kind for j in per_job),
                       "succeeded": sum(j["kind"] == kind and j["status"] == "succeeded" for j in per_job),
                       "run_s_median": _median([j["run_s"] for j in mine]),
                       "cpu_s_median": _median([j["cpu_s"] for j in mine]),
                       "run_s_median_by_case": {c: _median([j["run_s"] for j in mine if j["case"] == c])
                                                for c in dict.fromkeys(j["case"] for j in mine)},
                       "jobs_per_minute": round(60 * len(mine) / run, 2) if run else None}
    return {
        "mix": {"geometry": args.geometry, "guided": args.guided, "scenes": args.scenes, "preset": args.preset,
                "scene_objects": 1 + len(SCENE_STEPS), "model": "random:tiny", "torch_threads": 1},
        "overall": {"jobs": len(per_job), "succeeded": sum(j["status"] == "succeeded" for j in per_job),
                    "wall_s": round(wall, 2), "jobs_per_minute": round(60 * len(per_job) / wall, 2) if wall else None,
                    "busy_s": round(sum(j["run_s"] or 0 for j in per_job), 2),
                    "cpu_s": round(sampler.cpu_at(last_finish) - sampler.cpu_at(first_submit), 2)},
        "kinds": kinds,
        "jobs": per_job,
        "memory_mb": {"worker_rss_idle": round(idle[2], 1), "worker_rss_peak": round(max(s[2] for s in during), 1),
                      "worker_rss_after": round(after[2], 1), "worker_hwm": round(hwm["worker"], 1),
                      "children_rss_idle": round(idle[3], 1), "children_rss_peak": round(max(s[3] for s in during), 1),
                      "children_rss_after": round(after[3], 1),
                      "children_hwm": {p: round(v, 1) for p, v in hwm["children"].items()}},
        "idle_cpu_s_per_s": round(idle_cpu_rate, 4),
        "load_average_1m": round(os.getloadavg()[0], 2),
    }


def table(figures: dict) -> str:
    """The figures as two markdown tables: throughput per kind, and the worker's memory."""
    lines = ["| jobs | succeeded | run s (median) | worker CPU s (median) | jobs per minute |", "|---|---|---|---|---|"]
    for kind, k in figures["kinds"].items():
        lines.append(f"| {k['jobs']} {kind} | {k['succeeded']} | {k['run_s_median']} | {k['cpu_s_median']} | "
                     f"{k['jobs_per_minute']} |")
    o = figures["overall"]
    lines.append(f"| all {o['jobs']}, wall {o['wall_s']} s (CPU {o['cpu_s']} s) | {o['succeeded']} | | | "
                 f"**{o['jobs_per_minute']}** |")
    m = figures["memory_mb"]
    lines += ["", "| resident MB | idle after start | peak during the mix | after the mix | high-water mark |",
              "|---|---|---|---|---|",
              f"| worker process | {m['worker_rss_idle']} | {m['worker_rss_peak']} | {m['worker_rss_after']} | "
              f"{m['worker_hwm']} |",
              f"| its children (mesh loader) | {m['children_rss_idle']} | {m['children_rss_peak']} | "
              f"{m['children_rss_after']} | {sum(m['children_hwm'].values()):.1f} |"]
    return "\n".join(lines)


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of ``pid`` (0 once it is gone)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / TICK_S


def _status_mb(pid: int, key: str) -> float:
    """A ``/proc/<pid>/status`` memory line (``VmRSS``, ``VmHWM``) in MB (0 once the process is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{key}:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _epoch(stamp: str | None) -> float | None:
    return None if stamp is None else datetime.fromisoformat(stamp.replace("Z", "+00:00")).timestamp()


def _median(values: list[float]) -> float | None:
    return round(statistics.median(values), 2) if values else None


if __name__ == "__main__":
    sys.exit(main())
