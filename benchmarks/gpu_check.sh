#!/bin/bash
# The GPU checks, in one call on a machine with an NVIDIA GPU (docs/benchmarks.md, "On a GPU"): the CUDA tests,
# then `ctp bench --device cuda` on the dev cases (`default` and `fast`, oracle guide through random:ViT-B-32), all
# written to one log. Such a machine may have no network: what it lacks is installed from the wheels carried in
# .whl/ (benchmarks/gpu_wheels.sh makes them here) and the cases are read from .bench/.
# Usage (repo root): benchmarks/gpu_check.sh [OUT_DIR]   (OUT_DIR defaults to $OUT, else ./gpu-check)
# CTP_GPU_CHECK_DEVICE=cpu and CTP_GPU_CHECK_CASES=<ids> run the same steps on the CPU on a few cases (a dry run).
set -uo pipefail
cd "$(dirname "$0")/.."
out=${1:-${OUT:-gpu-check}}
mkdir -p "$out"
log="$out/gpu_check.log"
work=$(mktemp -d)  # the bench's folders (plots and all) stay here
device=${CTP_GPU_CHECK_DEVICE:-cuda}
cases=${CTP_GPU_CHECK_CASES:+--cases $CTP_GPU_CHECK_CASES}
python=${PYTHON:-python3}
export OMP_WAIT_POLICY=PASSIVE PYTHONUNBUFFERED=1
{
  echo "== gpu_check $(date -u +%FT%TZ) commit $(git rev-parse --short HEAD 2>/dev/null || echo '?') device $device"
  command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv
  export PYTHONPATH=$PWD
  if ! "$python" -c "import trimesh, manifold3d, rtree, embreex, pydantic" 2>/dev/null; then
    ls .whl/*.whl >/dev/null 2>&1 || { echo "the engine's packages are missing and no .whl/ came: run benchmarks/gpu_wheels.sh here and carry .whl"; exit 1; }
    "$python" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/ctp-site \
      .whl/*.whl || { echo "installing the carried wheels failed"; exit 1; }
    export PYTHONPATH=/tmp/ctp-site:$PWD
  fi
  "$python" -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
  echo "== CUDA tests"
  "$python" -m pytest -q -rs -p no:cacheprovider tests/test_guidance.py tests/test_render.py -k cuda
  [ -d .bench ] || { echo ".bench/ is missing: run benchmarks/gpu_wheels.sh here and carry .bench"; exit 1; }
  for preset in default fast; do
    echo "== ctp bench --preset $preset --device $device"
    "$python" -m ctp bench .bench --with-reference --method ctp --guide oracle --model random:ViT-B-32 \
      --preset "$preset" --device "$device" $cases --out "$work/bench-$preset" --quiet
    cp "$work/bench-$preset/results.jsonl" "$out/results-$preset.jsonl"  # $OUT takes few files: the rows, the log
    grep -A3 "^| variant" "$work/bench-$preset/summary.md"
    "$python" - "$work/bench-$preset/results.jsonl" <<'PY'
import json, statistics, sys
rows = [json.loads(line) for line in open(sys.argv[1])]
times = [r["time_s"] for r in rows if r.get("status") == "ok"]
images = [r["clip_images"] for r in rows if r.get("status") == "ok"]
placed = sum(bool(r.get("metrics", {}).get("placement_success")) for r in rows)
print(f"cases {len(rows)}: time median {statistics.median(times):.2f} s, mean {statistics.mean(times):.2f} s; "
      f"encoder images median {statistics.median(images):.0f}; placed {placed}/{len(rows)}")
PY
  done
  echo "== end $(date -u +%FT%TZ)"
} 2>&1 | tee "$log"
