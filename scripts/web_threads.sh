#!/usr/bin/env bash
# The page's threaded build: the same crate with wasm atomics and shared memory (feature
# `wasm-threads`), whose loops (`par`) and linear algebra (`krr::linalg`) split over a pool of
# Web Workers (wasm-bindgen-rayon). web/worker.js loads it where the page is cross-origin
# isolated and falls back to the plain build (trunk's) elsewhere; both give the same bits.
#
# Trunk runs this after each build (Trunk.toml's post_build hook, TRUNK_STAGING_DIR set), so
# `trunk build` and `trunk serve` both ship it as threads/: nkrr.js, nkrr_bg.wasm and the pool's
# worker snippet. By hand: `bash scripts/web_threads.sh OUT_DIR` writes OUT_DIR/threads.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
source scripts/wasm-env.sh
out="${1:-${TRUNK_STAGING_DIR:?run by trunk, or give the output folder}}/threads"
# Its own target folder: other flags than the plain build's, which stays warm.
export CARGO_TARGET_DIR="$ROOT/target/web-threads"
# Shared memory needs atomics and bulk memory in every object, std's (build-std) and
# meshoptimizer's C++ too, and an explicit maximum: 4 GiB, what the plain build may grow to.
# wasm-bindgen finds the imported shared memory and the TLS exports and writes thread-aware glue.
export CARGO_TARGET_WASM32_UNKNOWN_UNKNOWN_RUSTFLAGS="$CARGO_TARGET_WASM32_UNKNOWN_UNKNOWN_RUSTFLAGS \
-C target-feature=+atomics,+bulk-memory,+mutable-globals \
-C link-arg=--shared-memory -C link-arg=--import-memory -C link-arg=--max-memory=4294967296 \
-C link-arg=--export=__wasm_init_tls -C link-arg=--export=__tls_size \
-C link-arg=--export=__tls_align -C link-arg=--export=__tls_base"
export CFLAGS_wasm32_unknown_unknown="-matomics -mbulk-memory" CXXFLAGS_wasm32_unknown_unknown="-matomics -mbulk-memory"
cargo build --release --target wasm32-unknown-unknown --no-default-features --features wasm-threads
rm -rf "$out"
wasm-bindgen --target web --no-typescript --out-dir "$out" --out-name nkrr \
    "$CARGO_TARGET_DIR/wasm32-unknown-unknown/release/nkrr.wasm"
# The plain build's optimisation level (index.html's data-wasm-opt), with the features it uses.
wasm-opt -O3 --enable-threads --enable-bulk-memory --enable-simd --enable-mutable-globals \
    --enable-sign-ext --enable-nontrapping-float-to-int --enable-reference-types \
    "$out/nkrr_bg.wasm" -o "$out/nkrr_bg.wasm"
echo "web_threads: $out ($(du -sh "$out" | cut -f1))"
