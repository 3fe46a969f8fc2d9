"""How much a job's data size (``VmData``, what ``CTP_JOB_MEMORY_MB`` limits: ``worker.memory.job_memory``) grows
over its value at the job's start, for the jobs ``tests/test_job_memory.py`` sizes its ceiling by. A measurement,
not a test: it prints numbers.

Runs as a worker does, in one process: the native thread pools warmed (``worker.memory``), the guide preloaded
(``random:tiny``), one torch thread, then ``ctp_core.align.align`` on a box target and an icosphere source of
each ``--subdivisions`` (2: 320 faces, the service tests' ball; 6: 81,920 faces), ``--runs`` times each, with no
ceiling. A thread reads ``VmData`` from /proc every ``--sample-s``; the peak over the start is printed per run.
Transient arrays mapped and unmapped between two samples are missed, so a peak is a lower bound; and since glibc
reuses heap an earlier job left behind, later runs of a size can peak lower or higher than the first.

    PYTHONPATH=$PWD OMP_NUM_THREADS=1 .venv/bin/python benchmarks/job_memory.py --subdivisions 2 6 --runs 4
"""

from __future__ import annotations

import argparse
import os
import threading
import time

MiB = 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subdivisions", type=int, nargs="+", default=[2, 6], help="icosphere levels of the source")
    parser.add_argument("--runs", type=int, default=4, help="jobs per source")
    parser.add_argument("--preset", default="test")
    parser.add_argument("--sample-s", type=float, default=0.0003)
    args = parser.parse_args()
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

    import torch
    import trimesh

    from ctp_core.align import align
    from ctp_core.config import AlignConfig
    from ctp_core.guide.loaders import get_guide
    from worker.memory import _vm_data_bytes, _warm_native

    torch.set_num_threads(1)
    _warm_native()
    config = AlignConfig.model_validate({"preset": args.preset, "model": "random:tiny"})
    guide = get_guide("random:tiny")
    target = trimesh.creation.box()
    peak = [0]

    def sample() -> None:
        while True:
            peak[0] = max(peak[0], _vm_data_bytes() or 0)
            time.sleep(args.sample_s)

    threading.Thread(target=sample, daemon=True).start()  # its stack is charged before any job starts
    time.sleep(0.1)
    print(f"VmData with the model loaded: {_vm_data_bytes() / MiB:.0f} MB")
    for level in args.subdivisions:
        source = trimesh.creation.icosphere(subdivisions=level, radius=0.3)
        for run in range(args.runs):
            start = peak[0] = _vm_data_bytes() or 0
            began = time.perf_counter()
            align(target, source, "a ball on top of a box", config, guide=guide)
            seconds = time.perf_counter() - began
            end = _vm_data_bytes() or 0
            print(f"{len(source.faces):>6} faces, run {run}: peak +{(peak[0] - start) / MiB:.0f} MB over the start, "
                  f"+{(end - start) / MiB:.0f} MB at the end, {seconds:.1f} s", flush=True)


if __name__ == "__main__":
    main()
