"""How long one pair placement takes: two trees back to back, and where the time goes.

  python benchmarks/pair_speed.py compare --before DIR --after DIR CASE_DIR... [--rounds 3] [--guide none]
      each round runs every case once per tree, the trees' order alternating round by round (load drifts on a
      shared machine), each run a fresh process as `ctp bench` runs one case (the bench's start, seed 0, the
      default preset; guide none: `--method geometry`, oracle: `--method ctp --guide oracle`): per case the
      median of the align call and of the whole process (imports and loading included), whether the two trees
      placed the source the same, and the ratio of the pair medians; a markdown table last
  python benchmarks/pair_speed.py cli --before DIR --after DIR CASE_DIR... [--rounds 3]
      the same for the command a user types, `ctp align TARGET SOURCE --prompt P --no-guidance`, timed as a whole
      (its "align" time is the seconds the command reports: the placement and writing its GLB)
  python benchmarks/pair_speed.py scene --before DIR --after DIR SCENE_DIR... [--rounds 3]
      the same for a described scene (../shared/bench/scenes/<id>), `ctp compose` as its run.sh runs it
      (`--no-guidance --seed 7`); "same placement": the objects' placements the command prints are equal
  python benchmarks/pair_speed.py profile CASE_DIR... [--guide none] [--out profile.txt]
      pyinstrument's call tree over the cases in one process, after one warm-up run (imports left out)
  python benchmarks/pair_speed.py encodes CASE_DIR... [--guide oracle]
      the images the guide encodes in one placement of each case, by the search's stage that asked for them (the
      coarse stage, the guide's noise probes and its agreement check, the fine stage; "refinement and swept turns"
      for the rest) and the goal's own views; one JSON line per case
  python benchmarks/pair_speed.py one CASE_DIR [--guide none]
      one run in this process: one JSON line (what `compare` starts per run)

DIR is a checkout of this project (a `git worktree` of another commit, say); its ctp_core is the one imported.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def _config(guide: str, model: str, threads: int):
    from ctp_core.bench.harness import BenchOptions

    options = BenchOptions(seed=0, threads=threads, model=model if guide == "oracle" else None)
    return options.config("geometry" if guide == "none" else "ctp")


def _align(folder: Path, guide: str, model: str, threads: int) -> tuple[dict, object]:
    """One placement as `ctp bench` runs it: the protocol's start 0, seed 0; the oracle goal where asked."""
    from ctp_core.align import align
    from ctp_core.bench import protocol
    from ctp_core.bench.cases import read_case

    config = _config(guide, model, threads)
    case = read_case(folder / "case.json")
    started = time.perf_counter()
    target, source = case.load()
    loaded = time.perf_counter()
    init = protocol.initial_poses(case.reference, source.bounds, protocol="rigid", count=1, seed=0,
                                  case_id=case.id)[0]
    extra = {}
    if guide == "oracle":
        from ctp_core.guide import goals, loaders

        extra = {"guide": loaders.guide_for(config), "goal": goals.ReferenceGoal(case.reference)}
    began, cpu = time.perf_counter(), time.process_time()
    result = align(target, source, case.prompt, config, init=init, target_name=case.target_name,
                   source_name=case.source_name, **extra)
    row = {"case": case.id, "load_s": round(loaded - started, 3), "align_s": round(time.perf_counter() - began, 3),
           "align_cpu_s": round(time.process_time() - cpu, 3), "pose": result.source_to_target.tolist()}
    return row, result


def one(args) -> None:
    t0 = time.perf_counter()
    import ctp_core.align  # noqa: F401  the engine's imports, timed alone

    imported = time.perf_counter() - t0
    row, _ = _align(args.case, args.guide, args.model, args.threads)
    print(json.dumps({"import_s": round(imported, 3), **row}))


def profile(args) -> None:
    from pyinstrument import Profiler

    _align(args.cases[0], args.guide, args.model, args.threads)  # warm: imports, first-use caches
    profiler = Profiler(interval=0.002)
    profiler.start()
    for folder in args.cases:
        _align(folder, args.guide, args.model, args.threads)
    profiler.stop()
    text = profiler.output_text(unicode=True, color=False)
    if args.out:
        args.out.write_text(text)
    print(text)


# ``encodes``: the search's functions a count is filed under, innermost first
STAGES = ("agreement_views", "guide_noise", "_fine", "tile_score", "_coarse")


def encodes(args) -> None:
    from collections import Counter

    from ctp_core import objective
    from ctp_core.search import coarse_to_fine

    inside: list[str] = []

    def within(name: str, fn):
        def call(*a, **k):
            inside.append(name)
            try:
                return fn(*a, **k)
            finally:
                inside.pop()
        return call

    def counted(fn, kind: str):
        def call(scorer, *a, **k):
            before = scorer.clip_images
            out = fn(scorer, *a, **k)
            stage = next((s for s in reversed(inside) if s in STAGES), "refinement and swept turns")
            tally[f"{kind}{stage.strip('_')}"] += scorer.clip_images - before
            return out
        return call

    for name in STAGES:
        setattr(coarse_to_fine, name, within(name, getattr(coarse_to_fine, name)))
    objective.Scorer.clip_term = counted(objective.Scorer.clip_term, "")
    objective.Scorer.embed_goal = counted(objective.Scorer.embed_goal, "goal's views: ")
    for folder in args.cases:
        tally: Counter = Counter()
        row, result = _align(folder, args.guide, args.model, args.threads)
        print(json.dumps({"case": row["case"], "clip_images": result.clip_images, "align_s": row["align_s"],
                          **dict(tally.most_common())}))


def _run(command: list[str], tree: Path) -> tuple[float, float, str]:
    """The command's wall time, its CPU time (user + system, its children's included) and its last line."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    before, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True, check=False)
    wall, after = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode:
        raise SystemExit(f"{' '.join(command)} in {tree} failed:\n{done.stderr[-2000:]}")
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return wall, cpu, done.stdout.strip().splitlines()[-1]


def _command(args, folder: Path) -> tuple[str, list[str], str]:
    """The command a user types for ``folder`` (`cli`: a pair's `ctp align`; `scene`: `ctp compose` as the scenes'
    run.sh runs it), before its common flags: the case's id, the arguments, and the summary's key for its pose."""
    if args.what == "cli":
        case = json.loads((folder / "case.json").read_text())
        return case["id"], ["align", str(folder / case["target"]["file"]), str(folder / case["source"]["file"]),
                            "--prompt", case["prompt"], "--target-name", case["target"]["name"],
                            "--source-name", case["source"]["name"]], "translation"
    scene = json.loads((folder / "scene.json").read_text())
    names = ["--names", *scene["names_flag"]] if scene.get("names_flag") else []
    return scene["id"], ["compose", *(str(folder / o["file"]) for o in scene["objects"]), "--prompt",
                         scene["sentence"], *names, "--seed", "7"], "objects"


def _measure(args, tree: Path, folder: Path) -> dict:
    if args.what in ("cli", "scene"):
        case, command, pose = _command(args, folder)
        with tempfile.TemporaryDirectory() as out:
            wall, cpu, line = _run([sys.executable, "-m", "ctp", *command, "--no-guidance", "--threads",
                                    str(args.threads), "--quiet", "--out", f"{out}/scene.glb"], tree)
        summary = json.loads(line)
        return {"case": case, "process_s": round(wall, 3), "process_cpu_s": round(cpu, 3),
                "align_s": summary["seconds"], "pose": [summary[pose], summary.get("scale")]}
    wall, cpu, line = _run([sys.executable, str(Path(__file__).resolve()), "one", str(folder), "--guide",
                            args.guide, "--model", args.model, "--threads", str(args.threads)], tree)
    return {**json.loads(line), "process_s": round(wall, 3), "process_cpu_s": round(cpu, 3)}


def compare(args) -> None:
    trees = {"before": args.before.resolve(), "after": args.after.resolve()}
    rows: list[dict] = []
    for round_ in range(args.rounds):
        order = list(trees) if round_ % 2 == 0 else list(reversed(trees))
        for folder in args.cases:
            for name in order:
                row = {"round": round_, "tree": name, **_measure(args, trees[name], folder),
                       "loadavg": round(os.getloadavg()[0], 2)}
                rows.append(row)
                print(json.dumps({k: v for k, v in row.items() if k != "pose"}), flush=True)
    cases = list(dict.fromkeys(r["case"] for r in rows))

    def median(tree: str, case: str, key: str) -> float:
        return statistics.median(r[key] for r in rows if r["tree"] == tree and r["case"] == case)

    def same(case: str) -> bool:
        poses = [json.dumps(r["pose"]) for r in rows if r["case"] == case]
        return len(set(poses)) == 1

    keys = {"align_s": "align call, wall s" if args.what == "compare" else "command's seconds, wall",
            "align_cpu_s": "align call, CPU s", "process_s": "whole process, wall s",
            "process_cpu_s": "whole process, CPU s"}
    keys = {k: label for k, label in keys.items() if all(k in r for r in rows)}  # `cli` has no align CPU
    lines = ["| case | " + " | ".join(f"{label}: before → after" for label in keys.values()) + " | same placement |",
             "|---|" + "---|" * len(keys) + "---|"]
    for case in cases:
        cells = [f"{median('before', case, k):.2f} → {median('after', case, k):.2f}" for k in keys]
        lines.append(f"| {case} | {' | '.join(cells)} | {'yes' if same(case) else 'NO'} |")
    totals = {}
    for key in keys:
        totals[key] = (statistics.median(median("before", c, key) for c in cases),
                       statistics.median(median("after", c, key) for c in cases))
    cells = [f"{b:.2f} → {a:.2f} (**{b / a:.2f}x**)" for b, a in totals.values()]
    lines.append(f"| median | {' | '.join(cells)} | |")
    print(json.dumps({"bench": f"pair_speed_{args.what}", "guide": args.guide, "rounds": args.rounds,
                      "threads": args.threads, "cases": cases,
                      **{f"{k}_median_{t}": round(v[i], 3) for k, v in totals.items()
                         for i, t in enumerate(("before", "after"))},
                      "all_same": all(same(c) for c in cases)}))
    print("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    for name in ("compare", "cli", "scene", "profile", "encodes", "one"):
        p = sub.add_parser(name)
        if name in ("compare", "cli", "scene"):
            p.add_argument("--before", type=Path, required=True)
            p.add_argument("--after", type=Path, required=True)
            p.add_argument("--rounds", type=int, default=3)
        if name == "one":
            p.add_argument("case", type=Path)
        else:
            p.add_argument("cases", type=Path, nargs="+")
        if name == "profile":
            p.add_argument("--out", type=Path)
        p.add_argument("--guide", choices=("none", "oracle"), default="oracle" if name == "encodes" else "none")
        p.add_argument("--model", default="random:ViT-B-32", help="the oracle guide's encoder")
        p.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    {"compare": compare, "cli": compare, "scene": compare, "profile": profile, "encodes": encodes,
     "one": one}[args.what](args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
