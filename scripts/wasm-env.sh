# Sourced by the scripts that build for the browser. rustup has no wasm32 std on these
# machines, so the web build uses Debian's rustc-web with its rust-src and builds std itself.
# Kept out of native builds: they use rustup's toolchain and no build-std.
export RUSTC=/usr/bin/rustc
export RUSTDOC=/usr/bin/rustdoc
export RUSTC_BOOTSTRAP=1
export CARGO_UNSTABLE_BUILD_STD=std,panic_abort
# Separate target dir: another rustc, other flags; keeps native artifacts warm.
export CARGO_TARGET_DIR="$ROOT/target/web"
# trunk must use the pinned wasm-bindgen-cli and npm's binaryen (Debian's wasm-opt 108
# produces broken output), never download its own.
export PATH="$ROOT/node_modules/.bin:$HOME/.cargo/bin:$PATH"
export TRUNK_OFFLINE=true TRUNK_SKIP_VERSION_CHECK=true
# WebAssembly SIMD (simd128: every browser with WebGPU has it), for std too (build-std): the
# tuning's f64 m × m algebra runs on the worker's CPU at every step (tests/browser/tuning-step).
export CARGO_TARGET_WASM32_UNKNOWN_UNKNOWN_RUSTFLAGS="-C target-feature=+simd128"
# meshoptimizer's C++ (the meshopt crate) for wasm32: Debian's clang and llvm-ar of the same
# LLVM as lld.
export CC_wasm32_unknown_unknown=clang-22 CXX_wasm32_unknown_unknown=clang++-22 AR_wasm32_unknown_unknown=llvm-ar-22
