"""Auto-Align on the benchmark targets: is up recovered, and is an upright upload left alone?

For every target in the bench folder: (1) the file as authored must come back unchanged (identity);
(2) under ``--trials`` uniformly random rotations the recovered up, taken back to the file frame, must
be within 10° of the file's +Y. A second, symmetry-aware figure also counts an answer whose height
profile along it matches the one along +Y (a cube or a sphere has no single up to find). Prints one
JSON object: per case and totals.

``--model SPEC`` adds the semantic judge (``upright.upright_judge``: renders under candidate ups scored
against "a photo of a NAME", NAME from case.json); it needs real weights to mean anything, ``random:ARCH``
only exercises the path.

    python benchmarks/canonical_bench.py [--bench ../shared/bench] [--trials 20] [--seed 0] [--model SPEC]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ctp_core import io
from ctp_core.geometry import sampling
from ctp_core.guide import guidance, loaders
from ctp_core.guide.upright import upright_judge
from ctp_core.orientation import canonical

_TOLERANCE_DEG = 10.0


def height_profile(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Sorted heights of surface samples along ``up``, as shares of their range."""
    heights = np.sort(points @ up)
    return (heights - heights[0]) / max(heights[-1] - heights[0], 1e-12)


def upright(mesh, guide: guidance.Guide | None, name: str, args: argparse.Namespace) -> canonical.Upright:
    """Auto-Align by geometry, or with the semantic judge when a guide is given."""
    judge = upright_judge(mesh, guide, name, views=args.views) if guide else None
    return canonical.upright_rotation(mesh, seed=args.seed, judge=judge)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "bench")
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model", help="guidance model spec for the semantic judge (default: geometry only)")
    parser.add_argument("--views", type=int, default=4, help="judge renders per candidate up")
    args = parser.parse_args()
    guide = loaders.get_guide(args.model) if args.model else None

    rng = np.random.default_rng(args.seed)
    cases, started = [], time.perf_counter()
    for path in sorted(args.bench.glob("*/*/target.glb")):
        mesh = io.load_mesh(path)
        points, _ = sampling.surface_samples(mesh, 4000, args.seed)
        reference = height_profile(points, np.array([0.0, 1.0, 0.0]))
        name = json.loads((path.parent / "case.json").read_text())["target"].get("name", "object").replace("_", " ")
        authored = upright(mesh, guide, name, args)
        strict = symmetric = 0
        seconds = []
        for rotation in Rotation.random(args.trials, random_state=rng):
            turned = mesh.copy()
            turned.apply_transform(np.block([[rotation.as_matrix(), np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]]))
            tick = time.perf_counter()
            up = rotation.inv().apply(upright(turned, guide, name, args).up)  # back to file frame
            seconds.append(time.perf_counter() - tick)
            hit = np.degrees(np.arccos(np.clip(up[1], -1, 1))) <= _TOLERANCE_DEG
            strict += int(hit)
            symmetric += int(hit or np.abs(height_profile(points, up) - reference).mean() < 0.01)
        cases.append({
            "case": f"{path.parent.parent.name}/{path.parent.name}",
            "faces": len(mesh.faces),
            "identity_kept": not authored.changed,
            "identity_reason": authored.reason,
            "up_within_10deg": strict / args.trials,
            "up_within_10deg_or_symmetric": symmetric / args.trials,
            "mean_s": round(float(np.mean(seconds)), 3),
        })
    count = len(cases)
    print(json.dumps({
        "trials_per_case": args.trials,
        "judge": args.model,
        "cases": cases,
        "totals": {
            "cases": count,
            "identity_kept": sum(c["identity_kept"] for c in cases) / max(count, 1),
            "up_within_10deg": sum(c["up_within_10deg"] for c in cases) / max(count, 1),
            "up_within_10deg_or_symmetric": sum(c["up_within_10deg_or_symmetric"] for c in cases) / max(count, 1),
            "cases_at_80pct": int(sum(c["up_within_10deg"] >= 0.8 for c in cases)),
            "wall_s": round(time.perf_counter() - started, 1),
        },
    }, indent=1))


if __name__ == "__main__":
    main()
