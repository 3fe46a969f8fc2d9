"""What a nearest-sample search costs: scipy's ``cKDTree`` against ``geometry.nearest.Tree`` (pykdtree), by the
number of points searched and of neighbours asked, on one thread and on several. The same tree of a surface's
samples (a sphere's), queries near the surface and far from it. A measurement, not a test: it prints numbers.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/nearest_search.py [--samples 6000] [--threads 2]

Each search is asked of a whole batch at once on the given threads (``nearest.Tree`` sets pykdtree's before each
search: ``nearest.PARALLEL_QUERY`` is where the run's threads start; here every size is timed on both counts).
``nearest.MANY`` is where scipy's tree takes over (many neighbours per point); each line also says whether both
found the same neighbours at the same distances.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from ctp_core.geometry import nearest  # noqa: E402


def _best(call, repeats: int) -> float:
    """The least of ``repeats`` timings of ``call``, in milliseconds (after one to warm)."""
    call()
    took = []
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        took.append(time.perf_counter() - started)
    return min(took) * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=6000, help="points in the tree (a surface's samples)")
    parser.add_argument("--threads", type=int, default=2, help="threads of the parallel searches")
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    sphere = rng.normal(size=(args.samples, 3))
    data = sphere / np.linalg.norm(sphere, axis=1, keepdims=True)
    scipy_tree, fast = cKDTree(data), nearest.Tree(data)
    print(f"points  k  scipy 1 thread  Tree 1 thread  ratio  scipy {args.threads}  Tree {args.threads}  "
          f"ratio  same (ms)")
    for count in (100, 1000, 8192, 64000):
        near = data[rng.integers(0, len(data), count // 2)] + rng.normal(0, 0.02, (count // 2, 3))
        queries = np.concatenate([near, rng.uniform(-4, 4, (count - count // 2, 3))])
        for k in (1, 2, 8, 32, 512):
            if k == 512 and count > 1000:
                continue
            row = []
            for threads in (1, args.threads):
                torch.set_num_threads(threads)
                threshold, nearest.PARALLEL_QUERY = nearest.PARALLEL_QUERY, 0  # every size on ``threads``
                row += [_best(lambda: scipy_tree.query(queries, k=k, workers=threads), args.repeats),  # noqa: B023
                        _best(lambda: fast.query(queries, k=k), args.repeats)]  # noqa: B023
                nearest.PARALLEL_QUERY = threshold
            want, got = scipy_tree.query(queries, k=k), fast.query(queries, k=k)
            same = np.array_equal(want[1], got[1]) and np.array_equal(want[0], got[0])
            print(f"{count:>6} {k:>3} {row[0]:>15.2f} {row[1]:>14.2f} {row[0] / row[1]:>6.2f} {row[2]:>8.2f} "
                  f"{row[3]:>7.2f} {row[2] / row[3]:>6.2f}  {'yes' if same else 'NO'}")


if __name__ == "__main__":
    main()
