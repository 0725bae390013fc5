#!/usr/bin/env bash
# Installs what nkrr's build and tests need, idempotently, on Debian 12 with
# only the package registries reachable. Each step checks before it installs.
#
#   scripts/setup.sh apt      Debian packages (wasm toolchain, lavapipe, chromium)
#   scripts/setup.sh wasm     wasm-bindgen-cli + trunk (pinned, from crates.io)
#   scripts/setup.sh npm      node tools (binaryen wasm-opt, gltf-validator, playwright-core,
#                             meshoptimizer's decoder, three.js)
#   scripts/setup.sh python   .venv with the training requirements (PyTorch CPU), and
#                             .venv-formats (laspy/lazrs, pye57, trimesh: fixtures, output loading)
#   scripts/setup.sh all      everything
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD

WASM_BINDGEN_VERSION=0.2.130   # must equal the wasm-bindgen crate version in Cargo.lock
TRUNK_VERSION=0.21.14          # 0.22 needs rustc >= 1.96.1, which we do not have

log() { printf '[setup] %s\n' "$*" >&2; }

as_root() { if [ "$(id -u)" = 0 ]; then "$@"; else sudo "$@"; fi; }

step_apt() {
    local pkgs=(rustc-web cargo-web rust-web-src rust-web-llvm lld-22 clang-22 llvm-22
                mesa-vulkan-drivers libvulkan1 chromium chromium-driver
                libusb-1.0-0 libgomp1 python3-venv)
    local missing=()
    for p in "${pkgs[@]}"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
    done
    if [ ${#missing[@]} -eq 0 ]; then log "apt: all present"; return; fi
    log "apt: installing ${missing[*]}"
    as_root apt-get update -qq
    DEBIAN_FRONTEND=noninteractive as_root apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
}

step_wasm() {
    # The lockfile must pin the same wasm-bindgen as the CLI, or the generated glue mismatches.
    if [ -f Cargo.lock ] && ! grep -A1 '^name = "wasm-bindgen"$' Cargo.lock | grep -q "\"$WASM_BINDGEN_VERSION\""; then
        log "Cargo.lock pins a wasm-bindgen other than $WASM_BINDGEN_VERSION"; exit 1
    fi
    if ! wasm-bindgen --version 2>/dev/null | grep -q "$WASM_BINDGEN_VERSION"; then
        log "installing wasm-bindgen-cli $WASM_BINDGEN_VERSION (~6 min)"
        # Not --locked: its lockfile pins a crate the registry no longer serves.
        cargo install -q wasm-bindgen-cli --version "$WASM_BINDGEN_VERSION"
    fi
    if ! trunk --version 2>/dev/null | grep -q "$TRUNK_VERSION"; then
        log "installing trunk $TRUNK_VERSION (~9 min)"
        cargo install -q trunk --version "$TRUNK_VERSION" --locked
    fi
    log "wasm tools: $(wasm-bindgen --version), $(trunk --version)"
}

step_npm() {
    if [ ! -x node_modules/.bin/wasm-opt ] || [ ! -d node_modules/gltf-validator ] || [ ! -d node_modules/playwright-core ] \
        || [ ! -f node_modules/meshoptimizer/meshopt_decoder.mjs ] || [ ! -d node_modules/three ]; then
        log "npm: installing from package-lock.json"
        npm ci --no-audit --no-fund --loglevel=error
    else
        log "npm: all present"
    fi
}

step_python() {
    if [ ! -x .venv/bin/python ]; then
        log "python: creating .venv"
        python3 -m venv .venv
    fi
    if ! .venv/bin/python -c 'import torch, numpy, skimage, scipy, trimesh, safetensors, pytest' 2>/dev/null; then
        log "python: installing training/requirements.txt (PyTorch is large)"
        .venv/bin/pip install -q --disable-pip-version-check -r training/requirements.txt
    else
        log "python: all present"
    fi
    if [ ! -x .venv-formats/bin/python ]; then
        log "python: creating .venv-formats"
        python3 -m venv .venv-formats
    fi
    if ! .venv-formats/bin/python -c 'import laspy, lazrs, pye57, trimesh, pytest, skimage' 2>/dev/null; then
        log "python: installing the format fixtures' writers and trimesh"
        .venv-formats/bin/pip install -q --disable-pip-version-check \
            -r tests/fixtures/formats/requirements.txt -r tests/formats/requirements.txt
    fi
}

what=${1:-all}
case "$what" in
    apt) step_apt ;;
    wasm) step_wasm ;;
    npm) step_npm ;;
    python) step_python ;;
    all) step_apt; step_wasm; step_npm; step_python ;;
    *) echo "usage: $0 [apt|wasm|npm|python|all]" >&2; exit 2 ;;
esac
