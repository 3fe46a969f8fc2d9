"""Nearest-sample search over fixed points (a surface's samples): a KD-tree built once, queried in batches.

The objective's terms, settling and the fields' builds ask for the one, two or eight samples nearest to many
points. pykdtree answers those queries with the same neighbours and distances as scipy's ``cKDTree`` (the same
exact search; ``tests/test_nearest.py`` checks both against a brute-force search) in about half the time for so few
neighbours (``benchmarks/kd_threads.py``); for many neighbours at once (``MANY``: the enclosed half asks for 512)
scipy's tree is faster, and is built for those on first use.

pykdtree runs a query on OpenMP's threads: ``use_threads`` holds them to the run's count as torch's are held, so a
run on one thread stays on one.

Frames: whatever frame the points are given in; queries are in the same one.
"""

from __future__ import annotations

import numpy as np
from pykdtree.kdtree import KDTree
from scipy.spatial import cKDTree

MANY = 32  # neighbours per point from which a query runs on scipy's tree (pykdtree keeps a sorted list per point)


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
        if k >= MANY or k > len(self.data) or not len(at):  # pykdtree: no padding past its points
            if self._many is None:
                self._many = cKDTree(self.data)
            dist, idx = self._many.query(at, k=k, distance_upper_bound=upper)
            return dist, idx.astype(np.int64, copy=False)
        dist, idx = self._tree.query(at, k=k, distance_upper_bound=None if np.isinf(upper) else upper)
        return dist, idx.astype(np.int64)


def use_threads(count: int) -> None:
    """Hold the searches' OpenMP threads to ``count`` (a run's ``AlignConfig.threads``, as torch's are held)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(count, user_api="openmp")
