#!/usr/bin/env bash
# Builds the web app (wasm + WebGPU) and serves it on http://127.0.0.1:8080.
# Installs what is missing first (idempotent). NKRR_BUILD_ONLY=1 builds dist/ and stops.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
bash scripts/setup.sh apt
bash scripts/setup.sh wasm
bash scripts/setup.sh npm
source scripts/wasm-env.sh
# The same cargo build trunk runs, done first and online: -Zbuild-std needs the standard
# library's own dependencies, which trunk's --offline build cannot fetch. Trunk then finds it
# built and only runs wasm-bindgen and wasm-opt (offline: it downloads no tools).
cargo build --release --target wasm32-unknown-unknown --no-default-features
trunk build --release --offline
if [ "${NKRR_BUILD_ONLY:-0}" = 1 ]; then exit 0; fi
echo "nkrr: serving dist/ on http://127.0.0.1:8080 (Ctrl-C to stop)"
exec trunk serve --release --offline --address 127.0.0.1 --port 8080
