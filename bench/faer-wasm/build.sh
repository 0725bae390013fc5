#!/usr/bin/env bash
# Builds the bench for wasm32 with the page's flags (scripts/wasm-env.sh of nkrr: Debian's rustc,
# build-std, +simd128, clang-22 for meshopt's C++), then wasm-bindgen --target nodejs into pkg/
# and wasm-opt -O3 (as trunk's data-wasm-opt="3") into pkg-opt/.
set -euo pipefail
cd "$(dirname "$0")"
# The same dependency versions as the page: the repository's lock file.
cp ../../Cargo.lock Cargo.lock
export RUSTC=/usr/bin/rustc RUSTDOC=/usr/bin/rustdoc RUSTC_BOOTSTRAP=1
export CARGO_UNSTABLE_BUILD_STD=std,panic_abort
export CARGO_TARGET_WASM32_UNKNOWN_UNKNOWN_RUSTFLAGS="-C target-feature=+simd128"
export CC_wasm32_unknown_unknown=clang-22 CXX_wasm32_unknown_unknown=clang++-22 AR_wasm32_unknown_unknown=llvm-ar-22
export CARGO_BUILD_JOBS=${CARGO_BUILD_JOBS:-1}
cargo build --release --target wasm32-unknown-unknown
WASM=target/wasm32-unknown-unknown/release/faer_wasm.wasm
~/.cargo/bin/wasm-bindgen --target nodejs --out-dir pkg "$WASM"
mkdir -p pkg-opt && cp pkg/* pkg-opt/
../../node_modules/.bin/wasm-opt -O3 pkg/faer_wasm_bg.wasm -o pkg-opt/faer_wasm_bg.wasm
