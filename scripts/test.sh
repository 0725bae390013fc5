#!/usr/bin/env bash
# Runs every test: native Rust tests (GPU kernels on Mesa's lavapipe), the training smoke test,
# then the browser tests against a release web build in Debian's headless Chromium (WebGPU on
# SwiftShader). Installs what is missing first (idempotent).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-$(mktemp -d)}"
mkdir -p artifacts

bash scripts/setup.sh all

echo "== native tests (cargo test)"
cargo test

echo "== scan-format fixtures: the committed files are what laspy/lazrs and pye57 write"
.venv-formats/bin/python tests/fixtures/formats/make_fixtures.py --check

echo "== output meshes load in trimesh (GLB, PLY, OBJ, STL)"
NKRR_BIN=target/debug/nkrr .venv-formats/bin/python -m pytest -q -p no:cacheprovider tests/formats

echo "== the error split of scripts/eval_metrics.py on synthetic meshes with a known answer; the GPU benchmark's driver (fakes, no runs)"
.venv-formats/bin/python -m pytest -q -p no:cacheprovider scripts/test_eval_metrics.py scripts/test_gpu_bench.py

echo "== the cloud readers against independent writers (laspy, pye57, Python's PLY and text): 3000 cases"
.venv-formats/bin/python scripts/fuzz_readers.py --cases 3000 --seed 1 --checker target/debug/examples/read_oracle --out target/fuzz-ci

echo "== training smoke test"
.venv/bin/python -m pytest -q -p no:cacheprovider training/test_smoke.py

echo "== web build"
NKRR_BUILD_ONLY=1 bash scripts/serve.sh

echo "== dist/ deploys anywhere: no live-reload code, built or served"
bash scripts/check_dist.sh

echo "== browser tests"
node --test --test-concurrency=1 tests/browser/
