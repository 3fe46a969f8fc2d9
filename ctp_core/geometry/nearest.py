"""Nearest-sample search over fixed points (a surface's samples): a KD-tree built once, queried in batches.

The objective's terms, settling and the fields' builds ask for the one to 32 samples nearest to many points.
pykdtree answers those queries with the same neighbours and distances as scipy's ``cKDTree`` (the same exact
search; ``tests/test_nearest.py`` checks both against a brute-force search) in half to four fifths of the time for
so few neighbours (``benchmarks/nearest_search.py``); for many neighbours at once (``MANY``: the enclosed half asks
for 512) scipy's tree is faster, and is built for those on first use.

Threads: a search of ``PARALLEL_QUERY`` points or more runs on the run's (torch's count, ``AlignConfig.threads``), a
smaller one on one: a parallel region waits for its slowest thread, and on a shared two-core worker the other core
is often busy. pykdtree's threads are those of the OpenMP runtime its wheel bundles, set before each search (where
it is built against the process's own runtime, that runtime's count applies).

Frames: whatever frame the points are given in; queries are in the same one.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from pykdtree.kdtree import KDTree
from scipy.spatial import cKDTree

MANY = 48  # neighbours per point from which a query runs on scipy's tree (pykdtree keeps a sorted list per point)
PARALLEL_QUERY = 8192  # query points from which a search runs on the run's threads (``benchmarks/nearest_search.py``)


class Tree:
    """A KD-tree of (M, 3) points; ``data`` holds them as float64."""

    def __init__(self, points: np.ndarray):
        self.data = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
        self._tree = KDTree(self.data)
        self._many: cKDTree | None = None

    def query(self, at: np.ndarray, k: int = 1, upper: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Distances and indices of the ``k`` nearest points to each of ``at`` (Q, 3), nearest first, as
        ``cKDTree.query`` gives them: (Q,) each for ``k`` 1, else (Q, k); only points nearer than ``upper``, a
        neighbour not found having distance inf and index ``len(data)``. Indices are int64."""
        at = np.ascontiguousarray(at, dtype=np.float64).reshape(-1, 3)
        threads = torch.get_num_threads() if len(at) >= PARALLEL_QUERY else 1
        if k >= MANY or k > len(self.data) or not len(at):  # pykdtree: no padding past its points
            if self._many is None:
                self._many = cKDTree(self.data)
            dist, idx = self._many.query(at, k=k, distance_upper_bound=upper, workers=threads)
            return dist, idx.astype(np.int64, copy=False)
        set_threads = _pykdtree_threads()
        if set_threads is not None:
            set_threads(threads)
        dist, idx = self._tree.query(at, k=k, distance_upper_bound=None if np.isinf(upper) else upper)
        return dist, idx.astype(np.int64)


@functools.cache
def _pykdtree_threads() -> Callable[[int], None] | None:
    """The thread count setter of the OpenMP runtime pykdtree's wheel bundles (threadpoolctl's), found once; None
    where it has none of its own."""
    from threadpoolctl import ThreadpoolController

    for lib in ThreadpoolController().select(user_api="openmp").lib_controllers:
        if any(part.startswith("pykdtree") for part in Path(lib.filepath).parts):
            return lib.set_num_threads
    return None
