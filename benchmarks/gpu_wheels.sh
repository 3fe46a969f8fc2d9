#!/bin/bash
# Prepare, on this machine, what benchmarks/gpu_check.sh needs on a GPU machine that has no network
# (the `device` tool's nvidia-h200: python3.12 with CUDA torch, transformers, onnxruntime, numpy, scipy,
# matplotlib, but none of the engine's geometry and config packages):
#   .whl/    cp312 manylinux wheels of those packages, at the versions this venv runs (no dependencies pulled)
#   .bench/  a copy of the dev cases (third-party data: ignored by git, never committed)
# Both folders are in .gitignore; name them in the device call's `carry`. Usage: benchmarks/gpu_wheels.sh [CASES_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
cases=${1:-../shared/bench}
pip=.venv/bin/pip
packages="trimesh manifold3d rtree embreex pydantic pydantic-core annotated-types typing-inspection pydantic-settings
python-dotenv"
rm -rf .whl && mkdir -p .whl
for name in $packages; do
  version=$($pip show "$name" | awk '/^Version:/{print $2}')
  python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
    --platform manylinux2014_x86_64 --platform manylinux1_x86_64 --platform any -d .whl "$name==$version"
done
rm -rf .bench && cp -r "$cases" .bench
du -sh .whl .bench
