"""The per-job memory ceiling of a worker process (``job_memory``, ``CTP_JOB_MEMORY_MB``): a job that outgrows it
fails ``job_too_large`` and the worker lives on (``worker.tasks`` runs every job and adjustment under it).
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from contextlib import contextmanager

from service.settings import MiB

log = logging.getLogger("ctp.worker")


_warned_no_ceiling = False


@contextmanager
def job_memory(budget_mb: int) -> Iterator[int | None]:
    """The per-job memory ceiling: a soft ``RLIMIT_DATA`` of this process's data size at job start plus
    ``budget_mb`` (``CTP_JOB_MEMORY_MB``; 0: none) while the job runs, restored after it; yields the budget
    in force, or None.

    ``RLIMIT_DATA`` (Linux 4.7+) counts private writable memory only: heap, anonymous mappings, thread
    stacks; not the shared libraries nor the address space that glibc's malloc arenas reserve per thread,
    which ``RLIMIT_AS`` would charge. Over it an allocation fails inside the job (``MemoryError``, torch's
    ``RuntimeError``): the job fails ``job_too_large`` and this worker lives on. Measured with torch and ONNX
    Runtime loaded: docs/service.md, "Memory ceiling". Between jobs (heartbeat, rq, Redis) nothing is limited.
    """
    global _warned_no_ceiling
    if not budget_mb:
        yield None
        return
    data = _vm_data_bytes()
    if data is None:
        if not _warned_no_ceiling:
            _warned_no_ceiling = True
            log.warning("CTP_JOB_MEMORY_MB=%d is not enforced on %s: no per-job memory ceiling (Linux only)",
                        budget_mb, sys.platform)
        yield None
        return
    import resource

    _warm_native()
    data = _vm_data_bytes() or data
    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    limit = data + budget_mb * MiB
    for bound in (soft, hard):  # an operator's own, lower, limit stays in force
        if bound != resource.RLIM_INFINITY:
            limit = min(limit, bound)
    resource.setrlimit(resource.RLIMIT_DATA, (limit, hard))
    try:
        yield budget_mb
    finally:
        resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))


_warm = False


def _warm_native() -> None:
    """Give the native libraries the buffers they keep for the life of the process, once, before any job runs
    under a ceiling. OpenBLAS (numpy's and scipy's) allocates its work buffers on first use and, when that
    allocation fails, retries forever (OpenMathLib/OpenBLAS#5289): a job that reached the ceiling in, say,
    its first ``scipy.spatial.Delaunay`` would hang instead of failing. Warmed, they reuse the buffers."""
    global _warm
    if _warm:
        return
    import numpy as np
    import scipy.linalg
    import torch

    square = np.asfortranarray(np.eye(1024) + 1.0)  # large enough that OpenBLAS runs it on all its threads
    square @ square
    np.linalg.svd(square[:64, :64])
    scipy.linalg.blas.dgemm(1.0, square, square)
    scipy.linalg.lu_factor(square[:64, :64])
    torch.ones(512, 512) @ torch.ones(512, 512)  # and torch's intra-op threads
    _warm = True


def _vm_data_bytes() -> int | None:
    """This process's private writable memory (``VmData``), or None where there is none to read (not Linux)."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        with open("/proc/self/status") as status:
            return next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmData:"))
    except (OSError, StopIteration, ValueError):
        return None
