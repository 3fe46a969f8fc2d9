"""Optimiser benchmarks (issue 3): one JSON line per measurement.

  python benchmarks/align_bench.py restarts CASE_DIR [--model random:ViT-B-32] [--steps 6] [--restarts 5]
      cost of N batched restarts relative to one (same steps, same views), from one process
  python benchmarks/align_bench.py geometry [BENCH_DIR]
      geometry-only sanity over the synthetic cases (contact and intersection after lambda_clip = 0)
  python benchmarks/align_bench.py case CASE_DIR [--preset default] [--model random:ViT-B-32]
      one full run: wall time and the per-phase split render / clip / geometry / eval / other
  python benchmarks/align_bench.py ratio CASE_DIR... [--fast default] [--slow descent] [--slow-steps 20]
      back to back per case, oracle guide and the rigid protocol start as in `ctp bench`: the fast preset in
      full, then the slow one over its first --slow-steps optimiser steps (cancelled there), its whole run
      extrapolated from the time per step (0 runs it in full)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from ctp_core.align import align  # noqa: E402
from ctp_core.bench.cases import discover, read_case  # noqa: E402
from ctp_core.bench.sanity import geometry_contact  # noqa: E402
from ctp_core.config import AlignConfig  # noqa: E402


def _run(case_dir: Path, config: AlignConfig):
    case = read_case(case_dir / "case.json")
    target, source = case.load()
    start = time.perf_counter()
    result = align(target, source, case.prompt, config, target_name=case.target_name,
                   source_name=case.source_name)
    return case, result, time.perf_counter() - start


def restarts(args) -> None:
    base = {"model": args.model, "optim": {"steps": args.steps, "phases": 1, "eval_every": args.steps}}
    times = {}
    for n in (1, args.restarts, 1, args.restarts):  # interleaved: load drifts on a shared machine
        cfg = AlignConfig.from_preset("descent", **{**base, "optim": {**base["optim"], "restarts": n}})
        _, result, _ = _run(args.case, cfg)
        times.setdefault(n, []).append(result.timings["optimise_total_s"])
    one, many = min(times[1]), min(times[args.restarts])
    print(json.dumps({"bench": "batched_restarts", "case": args.case.name, "model": args.model,
                      "steps": args.steps, "restarts": args.restarts, "seconds_1": one, "seconds_n": many,
                      "cost_ratio_n_over_1": round(many / one, 3),
                      "speedup_vs_sequential": round(args.restarts * one / many, 3)}))


def geometry(args) -> None:
    rows = [geometry_contact(case) for case in discover(args.bench / "synthetic")]
    for row in rows:
        print(json.dumps({"bench": "geometry_contact", **row}))
    checked = [r for r in rows if not r["penetration_allowed"]]
    print(json.dumps({"bench": "geometry_contact_summary", "cases": len(rows),
                      "passed": sum(r["passed"] for r in checked), "checked": len(checked)}))


def case(args) -> None:
    cfg = AlignConfig.from_preset(args.preset, model=args.model)
    case, result, wall = _run(args.case, cfg)
    print(json.dumps({"bench": "align_case", "case": case.id, "preset": args.preset, "model": args.model,
                      "wall_s": round(wall, 1), "timings": result.timings,
                      "phase_timings": result.phase_timings, "clip_images": result.clip_images}))


def _timed(case, preset: str, model: str, stop_after: int) -> dict:
    """One oracle-guided run from the case's rigid protocol start; cancelled after ``stop_after`` steps if > 0."""
    from ctp_core.bench import protocol
    from ctp_core.errors import Canceled
    from ctp_core.guide import goals

    target, source = case.load()
    init = protocol.initial_poses(case.reference, source.bounds, protocol="rigid", count=1, seed=0,
                                  case_id=case.id)[0]  # init 0 of `ctp bench --inits 1 --seed 0`
    cfg = AlignConfig.from_preset(preset, model=model)
    seen = {"step": 0, "first": None}

    def on_event(event) -> None:
        if event.stage == "refine" and event.kind == "phase_start" and seen["first"] is None:
            seen["first"] = time.perf_counter()  # refinement starts: preparation and model loading are over
        if event.stage == "refine":
            seen["step"] = event.step

    start = time.perf_counter()
    try:
        result = align(target, source, case.prompt, cfg, init=init, goal=goals.ReferenceGoal(case.reference),
                       target_name=case.target_name, source_name=case.source_name, on_event=on_event,
                       should_cancel=lambda: 0 < stop_after <= seen["step"])
    except Canceled:
        now = time.perf_counter()
        total = cfg.optim.steps
        per_step = (now - seen["first"]) / seen["step"]
        return {"preset": preset, "measured_s": round(now - start, 1), "steps_run": seen["step"], "steps": total,
                "extrapolated_s": round(seen["first"] - start + per_step * total, 1), "extrapolated": True}
    return {"preset": preset, "measured_s": round(time.perf_counter() - start, 1), "extrapolated": False,
            "clip_images": result.clip_images, "timings": result.timings}


def ratio(args) -> None:
    from ctp_core.guide.loaders import get_guide

    get_guide(args.model)  # loaded once for both presets, outside the timings (a worker keeps it loaded)
    for folder in args.cases:
        case = read_case(folder / "case.json")
        fast = _timed(case, args.fast, args.model, 0)
        slow = _timed(case, args.slow, args.model, args.slow_steps)
        slow_s = slow["extrapolated_s"] if slow["extrapolated"] else slow["measured_s"]
        print(json.dumps({"bench": "preset_time_ratio", "case": case.id, "model": args.model, "fast": fast,
                          "slow": slow, "ratio_slow_over_fast": round(slow_s / fast["measured_s"], 2),
                          "loadavg": os.getloadavg()}), flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("restarts")
    p.add_argument("case", type=Path)
    p.add_argument("--model", default="random:ViT-B-32")
    p.add_argument("--steps", type=int, default=6)
    p.add_argument("--restarts", type=int, default=5)
    p = sub.add_parser("geometry")
    p.add_argument("bench", type=Path, nargs="?", default=Path(__file__).resolve().parents[2] / "shared" / "bench")
    p = sub.add_parser("case")
    p.add_argument("case", type=Path)
    p.add_argument("--preset", default="default")
    p.add_argument("--model", default="random:ViT-B-32")
    p = sub.add_parser("ratio")
    p.add_argument("cases", type=Path, nargs="+")
    p.add_argument("--fast", default="default")
    p.add_argument("--slow", default="descent")
    p.add_argument("--slow-steps", type=int, default=20)
    p.add_argument("--model", default="random:ViT-B-32")
    args = parser.parse_args(argv)
    {"restarts": restarts, "geometry": geometry, "case": case, "ratio": ratio}[args.what](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
