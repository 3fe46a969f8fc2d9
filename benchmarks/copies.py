"""Several of a kind (issue 41): a small dev set of multi-copy prompts, per copy and for the set.

Cases: meshes of ``../shared/bench`` (read as ``io.load_mesh`` reads them, the bench's names) and generated ones
(the tests' scenes). For each: the copies' relation verdicts, whether any two intersect, the closest two copies'
gap, time per copy, and one placement of the same source (``align``, count 1) for the time a copy costs
against it. Geometry only (no guide): the machine has no model weights.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/copies.py --preset test
    PYTHONPATH=$PWD .venv/bin/python benchmarks/copies.py --preset default --only "three cups,gen: bowl"
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import trimesh

from ctp_core import io
from ctp_core.align import align
from ctp_core.assembly.copies import place_copies
from ctp_core.config import AlignConfig
from ctp_core.io import examples

BENCH = Path(__file__).resolve().parents[1] / ".." / "shared" / "bench"


def _bench(case: str) -> tuple[trimesh.Trimesh, trimesh.Trimesh, str, str]:
    folder = BENCH / case
    facts = json.loads((folder / "case.json").read_text())
    return (io.load_mesh(folder / facts["target"]["file"]), io.load_mesh(folder / facts["source"]["file"]),
            facts["target"]["name"], facts["source"]["name"])


def _disc() -> trimesh.Trimesh:
    disc = trimesh.creation.cylinder(radius=0.12, height=0.02, sections=32)
    return disc.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))


def cases() -> list[tuple[str, trimesh.Trimesh, trimesh.Trimesh, str, str, str]]:
    """(id, target, source, target name, source name, prompt)."""
    out = []
    for case, prompt in (("synthetic/s01", "three cups on the table"), ("synthetic/s02", "two balls inside the mug"),
                         ("synthetic/s06", "four cups around the box"),
                         ("synthetic/s01", "five cups in a row on the table"),
                         ("pairbench3d/coffee_cup_with_plate", "two coffee cups on a plate")):
        if (BENCH / case).is_dir():
            out.append((f"{case}: {prompt}", *_bench(case), prompt))
    box = trimesh.creation.box
    out += [
        ("gen: bowl", examples._bowl(), trimesh.creation.icosphere(subdivisions=2, radius=0.025), "bowl", "ball",
         "three balls in the bowl"),
        ("gen: around", box((1.2, 0.75, 0.8)), box((0.3, 0.5, 0.3)), "table", "chair", "six chairs around the table"),
        ("gen: row", box((1.0, 0.05, 0.3)), box((0.04, 0.25, 0.18)), "shelf", "book",
         "five books in a row on the shelf"),
        ("gen: stack", box((1.0, 0.75, 1.0)), _disc(), "table", "disc", "a stack of four discs on the table"),
    ]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="test")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", default="", help="comma-separated parts of case names to run (default: all)")
    args = parser.parse_args()
    only = [part for part in args.only.split(",") if part]
    config = AlignConfig.from_preset(args.preset, seed=args.seed, loss={"lambda_clip": 0.0})
    print("| case | arrangement | copies | relation holds | none intersect | min spacing | s per copy "
          "| one placement s |")
    print("|---|---|---|---|---|---|---|---|")
    for name, target, source, target_name, source_name, prompt in cases():
        if only and not any(part in name for part in only):
            continue
        t0 = time.perf_counter()
        align(target, source, prompt, config, target_name=target_name, source_name=source_name)
        single = time.perf_counter() - t0
        out = place_copies(target, source, prompt, config, target_name=target_name, source_name=source_name)
        m = out.metrics
        print(f"| {name} | {out.arrangement} | {out.count} | {m['relation_holds']}/{m['judged']} | "
              f"{m['none_intersect']} (IoU {m['max_iou']:.3f}) | {m['min_spacing']} | "
              f"{out.timings['mean_copy_s']:.2f} | {single:.2f} |", flush=True)


if __name__ == "__main__":
    main()
