"""Where the search loses the answer: per case, how close the proposals, the coarse ranking, the fine shortlist,
the kept starts and the refined answer come to the reference placement.

For each case with a reference (rigid protocol start, one init, as ``ctp bench``), the stages of ``align`` are run
one by one and, at each, the best rank held by a pose that *places* (centroid within
``metrics.PLACEMENT_RADIUS`` source diagonals of the reference's) is printed, with the nearest centroid error.
A miss whose proposals never place is the proposals'; one placed by proposals but ranked low is the guide's
(or the coarse views'); one kept but lost in refinement is the optimiser's. Measurement only: nothing here
changes a run.

    python benchmarks/search_recall.py ../shared/bench/pairbench3d ../shared/bench/synthetic --guide pixels
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from ctp_core import align, metrics
from ctp_core.bench import protocol
from ctp_core.bench.cases import discover
from ctp_core.bench.guides import guide_inputs
from ctp_core.config import AlignConfig
from ctp_core.geometry import sampling
from ctp_core.search import coarse_to_fine, ordering

CLOSE = 0.2  # ADD-S of a pose counted as close to the reference (success is 0.1)


def errors(pair, poses, reference: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 2) centroid error and ADD-S of each pose (source local -> normalised), as ``metrics.pose_errors``."""
    out = [metrics.pose_errors(points, pair.source_to_target(m), reference) for m in poses.matrices()]
    return np.array([[e["centroid_error"], e["adds"]] for e in out]).reshape(-1, 2)


def best_rank(errors: np.ndarray, key: ordering.Key | None) -> dict:
    """The best (0-based) rank by ``key`` (ascending; None: as given) of a pose that places and of one within
    ADD-S ``CLOSE``, and the nearest centroid error."""
    order = np.arange(len(errors)) if key is None else key.argsort().numpy()
    placed = np.flatnonzero(errors[order, 0] <= metrics.PLACEMENT_RADIUS)
    close = np.flatnonzero(errors[order, 1] <= CLOSE)
    return {"place": int(placed[0]) if len(placed) else None, "close": int(close[0]) if len(close) else None,
            "nearest": round(float(errors[:, 0].min()), 3) if len(errors) else None}


def run_case(case, args) -> dict:
    target, source = case.load()
    init = protocol.initial_poses(case.reference, source.bounds, protocol="rigid", count=1, seed=args.seed,
                                  case_id=case.id)[0]
    inputs = guide_inputs(args.guide, case, target, source, protocol.case_rng(args.seed, case.id, "guide"))
    overrides: dict = {}
    for item in args.set:
        path, value = item.split("=", 1)
        section, _, key = path.rpartition(".")
        if section:
            overrides.setdefault(section, {})[key] = json.loads(value)
        else:
            overrides[key] = json.loads(value)
    config = AlignConfig.from_preset(args.preset, seed=args.seed, model=args.model, **overrides)
    guide = inputs.guide
    if guide is None:
        from ctp_core.guide.loaders import guide_for
        guide = guide_for(config)
    started = time.perf_counter()
    run = align.prepare(target, source, case.prompt, config, guide=guide, goal=inputs.goal,
                        target_name=case.target_name, source_name=case.source_name)
    proposals = align.propose(run, init)
    ranked = coarse_to_fine.search(run.scorer, proposals, run.plan[0], k=config.optim.restarts)
    outcome = align.refine(run, ranked.poses, ranked.say)
    answer = align.result(run, outcome, case.prompt)
    row = {"case": case.id, "relation": case.relation, "seconds": round(time.perf_counter() - started, 1)}
    points = sampling.surface_samples(source, 500, args.seed)[0]
    regions = np.array(proposals.region)
    err = errors(run.pair, proposals.poses, case.reference, points)
    row["proposals"] = len(err)
    row["placing"] = {r: int((err[regions == r, 0] <= metrics.PLACEMENT_RADIUS).sum()) for r in sorted(set(regions))}
    row["close"] = {r: int((err[regions == r, 1] <= CLOSE).sum()) for r in sorted(set(regions))}
    for stage, (poses, key) in ranked.stages.items():
        row[stage] = best_rank(errors(run.pair, poses, case.reference, points), key)
    coarse_key = ranked.stages["coarse"][1]
    labels = proposals.region + ["sweep"] * (len(coarse_key) - len(proposals.region))
    row["coarse_best"] = [labels[i] for i in coarse_key.argsort()[:6].tolist()]
    row["kept"] = best_rank(errors(run.pair, ranked.poses, case.reference, points), None)
    final = metrics.pose_errors(points, answer.source_to_target, case.reference)
    refined = errors(run.pair, outcome.poses, case.reference, points)
    row["restarts"] = [{"centroid": round(float(e[0]), 3), "adds": round(float(e[1]), 3),
                        **{k: round(float(v), 4) for k, v in r.items() if k not in ("restart", "source_to_target")}}
                       for e, r in zip(refined, answer.restarts, strict=True)]
    row["chosen"] = answer.best_restart
    if args.poses:
        row["poses"] = [r["source_to_target"] for r in answer.restarts]
    row["final_centroid"] = round(final["centroid_error"], 3)
    row["final_adds"] = round(final["adds"], 3)
    return row


def case_parser(description: str) -> argparse.ArgumentParser:
    """The arguments every per-case instrument here takes: roots, model, preset, seed, case ids."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("roots", nargs="+", type=Path)
    parser.add_argument("--model", default="random:ViT-B-32")
    parser.add_argument("--preset", default="default")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cases", default="", help="comma-separated case ids (default: all with a reference)")
    return parser


def each_case(args: argparse.Namespace, run_case) -> int:
    """Print ``run_case(case, args)`` as one JSON line for every case with a reference under ``args.roots``."""
    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    ids = [c for c in args.cases.split(",") if c] or None
    cases = [c for root in args.roots for c in discover(root) if c.reference is not None and (not ids or c.id in ids)]
    for case in cases:
        print(json.dumps(run_case(case, args)), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = case_parser(__doc__.split("\n\n")[0])
    parser.add_argument("--guide", default="pixels", choices=["pixels", "oracle"])
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=JSON",
                        help="config override, e.g. search.fine=32 or autocast=false (repeatable)")
    parser.add_argument("--poses", action="store_true",
                        help="print each refined restart's 4x4 (source file -> target file)")
    return each_case(parser.parse_args(argv), run_case)


if __name__ == "__main__":
    sys.exit(main())
