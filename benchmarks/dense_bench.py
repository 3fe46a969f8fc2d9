"""Dense meshes at the full face budget, in bounded memory: ``ctp bench --method b1`` (the metrics and the
shrinkwrap baseline) and ``ctp align --preset test`` on a generated scan-like pair, each as a subprocess under
an address-space limit, reporting wall time, peak RSS and the exit status.

    python benchmarks/dense_bench.py [--target-subdivisions 7] [--source-subdivisions 7] [--limit-gib 8]

Icosphere subdivisions 7 give 327,680 faces; two of them are 655k faces in one pair, each mesh inside the
default 500k-face budget (``MeshLimits.max_faces``). CI runs the ~100k-face version (tests/test_large_meshes.py).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

REPO = Path(__file__).resolve().parents[1]


def bumpy_sphere(subdivisions: int, radius: float, seed: int) -> trimesh.Trimesh:
    """A scan-like closed surface: an icosphere with noisy radii."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.vertices *= (1.0 + 0.02 * np.random.default_rng(seed).standard_normal(len(mesh.vertices)))[:, None]
    return mesh


def write_case(root: Path, target_subdivisions: int, source_subdivisions: int) -> tuple[Path, int]:
    """A bench case folder ``root/dense-pair``: a ball on a ball, the source placed away from its reference."""
    folder = root / "dense-pair"
    folder.mkdir(parents=True)
    target = bumpy_sphere(target_subdivisions, 1.0, 0)
    source = bumpy_sphere(source_subdivisions, 0.3, 1)
    source.apply_translation((4.0, 2.0, -3.0))
    target.export(folder / "target.glb")
    source.export(folder / "source.glb")
    reference = np.eye(4)
    reference[:3, 3] = (-4.0, -0.7, 3.0)
    (folder / "case.json").write_text(json.dumps({
        "id": "dense-pair", "prompt": "a ball on top of a ball", "origin": "synthetic",
        "target": {"file": "target.glb", "name": "ball"}, "source": {"file": "source.glb", "name": "ball"},
        "reference": {"source_to_target": reference.tolist(), "scale": 1.0}, "relation": "on_top",
        "penetration_expected": False}))
    return folder, len(target.faces) + len(source.faces)


def run(args: list[str], limit_bytes: int, cwd: Path) -> dict:
    """One ``ctp`` command under RLIMIT_AS; its wall time and its peak RSS (the child's, from getrusage)."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_WAIT_POLICY": "PASSIVE"}
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "ctp", *args], cwd=cwd, env=env, capture_output=True, text=True,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes)))
    wall = time.perf_counter() - started
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # the largest child so far
    return {"command": args[0], "rc": done.returncode, "wall_s": round(wall, 1), "peak_rss_mb_so_far": round(peak_mb),
            "stderr_tail": done.stderr[-300:] if done.returncode else ""}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--target-subdivisions", type=int, default=7)
    parser.add_argument("--source-subdivisions", type=int, default=7)
    parser.add_argument("--limit-gib", type=float, default=8.0)
    args = parser.parse_args()
    limit = int(args.limit_gib * 2**30)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        case, faces = write_case(root / "cases", args.target_subdivisions, args.source_subdivisions)
        print(json.dumps({"faces": faces, "limit_gib": args.limit_gib}), flush=True)
        print(json.dumps(run(["bench", str(root / "cases"), "--method", "b1", "--preset", "test", "--out",
                              str(root / "out")], limit, root)), flush=True)
        rows = [json.loads(line) for line in (root / "out" / "results.jsonl").read_text().splitlines()]
        print(json.dumps({"bench_rows": [r["status"] for r in rows],
                          "contact": [r.get("metrics", {}).get("contact") for r in rows]}), flush=True)
        print(json.dumps(run(["align", str(case / "target.glb"), str(case / "source.glb"), "--prompt",
                              "a ball on a ball", "--preset", "test", "--model", "random:tiny", "--out",
                              str(root / "scene.glb"), "--quiet"], limit, root)), flush=True)


if __name__ == "__main__":
    main()
