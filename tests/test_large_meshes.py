"""Dense meshes in bounded memory: ``ctp bench`` (metrics, the shrinkwrap baseline) and ``ctp align`` on
a generated pair of ~100k faces (82k + 20k), run as subprocesses under an address-space limit.

The old ``trimesh.proximity.closest_point`` queries held every candidate triangle of every query point
at once (21 GB for a 69k-face scan); the limit here is what torch and the meshes need, with room."""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys

import numpy as np
import pytest

from benchmarks.dense_bench import write_case
from tests.conftest import REPO

LIMIT_BYTES = 6 * 2**30  # address space, torch's mappings included (an idle torch process maps ~2 GiB)


def _limited() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT_BYTES, LIMIT_BYTES))


def _ctp(*args: str, cwd) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE"}
    return subprocess.run([sys.executable, "-m", "ctp", *args], cwd=cwd, env=env, capture_output=True, text=True,
                          preexec_fn=_limited, timeout=900)


@pytest.fixture(scope="module")
def dense_case(tmp_path_factory):
    """82k + 20k faces: the benchmark's generated pair (benchmarks/dense_bench.py) at a CI-sized resolution."""
    root = tmp_path_factory.mktemp("dense")
    _, faces = write_case(root, target_subdivisions=6, source_subdivisions=5)
    return root, faces


@pytest.mark.slow
def test_bench_and_align_on_a_dense_pair_in_bounded_memory(dense_case, tmp_path):
    root, faces = dense_case
    assert faces > 100_000
    bench = _ctp("bench", str(root), "--method", "b1", "--preset", "test", "--out", str(tmp_path / "out"),
                 cwd=tmp_path)
    assert bench.returncode == 0, bench.stderr[-2000:]
    rows = [json.loads(line) for line in (tmp_path / "out" / "results.jsonl").read_text().splitlines()]
    assert [r["status"] for r in rows] == ["ok"], [r.get("error") for r in rows]
    assert all(np.isfinite(r["metrics"]["contact"]) for r in rows)
    case = root / "dense-pair"
    align = _ctp("align", str(case / "target.glb"), str(case / "source.glb"), "--prompt", "a ball on a ball",
                 "--preset", "test", "--model", "random:tiny", "--out", str(tmp_path / "scene.glb"), "--quiet",
                 cwd=tmp_path)
    assert align.returncode == 0, align.stderr[-2000:]
    assert (tmp_path / "scene.glb").stat().st_size > 1000
