"""What a nearest-sample search (``scipy.spatial.cKDTree.query``, k=2) costs on one thread and on several, by the
number of points searched: scipy starts its threads anew for every search, so a small search is slower on several.
``losses.PARALLEL_QUERY`` is where several start to pay. A measurement, not a test: it prints numbers.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/kd_threads.py [--samples 20000] [--workers 2]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=20000, help="points in the tree (a surface's samples)")
    parser.add_argument("--workers", type=int, default=2, help="threads of the parallel search")
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    tree = cKDTree(rng.random((args.samples, 3)))
    print(f"points  1 thread (ms)  {args.workers} threads (ms)  ratio")
    for count in (100, 1000, 4000, 8192, 16000, 64000):
        queries = rng.random((count, 3))
        took = []
        for workers in (1, args.workers):
            tree.query(queries, k=2, workers=workers)
            started = time.perf_counter()
            for _ in range(args.repeats):
                tree.query(queries, k=2, workers=workers)
            took.append((time.perf_counter() - started) / args.repeats * 1000)
        print(f"{count:>6}  {took[0]:>13.2f}  {took[1]:>14.2f}  {took[0] / took[1]:.2f}")


if __name__ == "__main__":
    main()
