"""What the prompt's relation costs a run: each case aligned with ``relation`` on and off in one process.

Run after run (``ctp bench`` and then its ``--ablation no-relation``) the difference is within this machine's
drift, and the first cases of a run carry the process's warm-up. Here each case is first aligned once untimed
(its meshes fill their caches: hull, ray intersector), then timed on, off, off, on or off, on, on, off
(alternating over the cases), so a drift in time cancels; printed per case as one JSON line, then a summary:
the ratio of the mean times and the median of the per-case ratios.

Measurement only: nothing here changes a run.

    python benchmarks/relation_time.py ../shared/bench/pairbench3d ../shared/bench/synthetic --guide geometry
"""

from __future__ import annotations

import json
import statistics
import sys
import time

from search_recall import case_parser, each_case  # a sibling script (benchmarks/ is on sys.path)

from ctp_core.align import align
from ctp_core.bench import protocol
from ctp_core.bench.guides import guide_inputs
from ctp_core.bench.harness import BenchOptions


def timed(case, target, source, init, args, relation: bool) -> float:
    """Seconds of one ``align`` of the case with the relation on or off, configured and guided as ``ctp bench``
    runs it (``--method geometry``, or ``ctp`` with ``--guide``, and ``--ablation no-relation`` when off)."""
    method = "geometry" if args.guide == "geometry" else "ctp"
    options = BenchOptions(methods=[method], preset=args.preset, seed=args.seed, model=args.model,
                           guide="text" if method == "geometry" else args.guide,
                           ablation=None if relation else "no-relation")
    inputs = None if method == "geometry" else guide_inputs(args.guide, case, target, source,
                                                             protocol.case_rng(args.seed, case.id, "guide"))
    started = time.perf_counter()
    align(target, source, case.prompt, options.config(method), init=init, target_name=case.target_name,
          source_name=case.source_name, guide=inputs.guide if inputs else None, goal=inputs.goal if inputs else None)
    return time.perf_counter() - started


def main(argv: list[str] | None = None) -> int:
    parser = case_parser(__doc__.split("\n\n")[0])
    parser.add_argument("--guide", default="geometry", choices=["geometry", "pixels", "oracle"])
    args = parser.parse_args(argv)
    rows: list[dict] = []

    def run_case(case, args) -> dict:
        target, source = case.load()
        init = protocol.initial_poses(case.reference, source.bounds, protocol="rigid", count=1, seed=args.seed,
                                      case_id=case.id)[0]
        first = len(rows) % 2 == 0
        timed(case, target, source, init, args, not first)  # untimed: the meshes' caches
        seconds = {True: 0.0, False: 0.0}
        for relation in (first, not first, not first, first):
            seconds[relation] += timed(case, target, source, init, args, relation) / 2
        rows.append({"case": case.id, "with_s": round(seconds[True], 3), "without_s": round(seconds[False], 3),
                     "ratio": round(seconds[True] / seconds[False], 3)})
        return rows[-1]

    each_case(args, run_case)
    if rows:
        mean = statistics.mean(r["with_s"] for r in rows) / statistics.mean(r["without_s"] for r in rows)
        print(json.dumps({"cases": len(rows), "ratio_of_means": round(mean, 3),
                          "median_ratio": statistics.median(r["ratio"] for r in rows)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
